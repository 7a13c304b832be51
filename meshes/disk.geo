// Unit disk centred at the origin, for the membrane obstacle scene.
//
// Parameters (override with `gmsh -setnumber NAME VALUE`):
//   n > 0  : structured boundary: each quarter circle gets n equal segments
//            (4n boundary vertices at the exact angles k*Pi/(2n), placed so the
//            boundary is exactly symmetric under x -> -x, y -> -y and
//            x <-> y); interior target size (Pi/2)/n.
//   n <= 0 : unstructured, target size h everywhere (boundary included).
//
// Physical groups: Curve "boundary" (tag 1) = the circle,
//                  Surface "domain" (tag 2).
// The centre (0,0) is always a mesh vertex (embedded point); no other node is
// written than the triangles' vertices. Triangles are counter-clockwise.
// Meshing is single-threaded with a fixed seed: the same parameters give a
// byte-identical .msh.

If (!Exists(n))
  n = 8;
EndIf
If (!Exists(h))
  h = 0.1;
EndIf

n = Round(n);
If (n > 0)
  lc = (Pi / 2) / n;
Else
  If (h <= 0)
    Error("disk.geo: need n > 0 or h > 0 (got n = %g, h = %g)", n, h);
    Abort;
  EndIf
  lc = h;
EndIf

Mesh.Algorithm = 6;              // Frontal-Delaunay: quasi-uniform triangles
Mesh.RandomSeed = 1;             // reproducible output
Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.MeshSizeFromCurvature = 0;
Mesh.MeshSizeExtendFromBoundary = 1;
Mesh.MeshSizeFromPoints = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;                // only elements of physical groups

Point(1) = {0, 0, 0, lc};        // the centre (and the arcs' centre)

If (n > 0)
  // Boundary points, counter-clockwise from (1,0). The first quadrant uses
  // cos/sin; the other quadrants are exact rotations of it by Pi/2.
  For q In {0 : 3}
    For k In {0 : n - 1}
      If (k == 0)
        c = 1; s = 0;
      Else
        c = Cos(k * Pi / (2 * n)); s = Sin(k * Pi / (2 * n));
      EndIf
      If (q == 0)
        x = c; y = s;
      ElseIf (q == 1)
        x = -s; y = c;
      ElseIf (q == 2)
        x = -c; y = -s;
      Else
        x = s; y = -c;
      EndIf
      Point(2 + q * n + k) = {x, y, 0, lc};
    EndFor
  EndFor
  // One arc per boundary segment (no interior nodes on the arcs).
  m = 4 * n;
  For i In {0 : m - 1}
    Circle(1 + i) = {2 + i, 1, 2 + (i + 1) % m};
    Transfinite Curve {1 + i} = 2;
  EndFor
  arcs[] = {1 : m};
Else
  Point(2) = {1, 0, 0, lc};
  Point(3) = {0, 1, 0, lc};
  Point(4) = {-1, 0, 0, lc};
  Point(5) = {0, -1, 0, lc};
  Circle(1) = {2, 1, 3};
  Circle(2) = {3, 1, 4};
  Circle(3) = {4, 1, 5};
  Circle(4) = {5, 1, 2};
  arcs[] = {1 : 4};
EndIf

Curve Loop(1) = arcs[];          // counter-clockwise
Plane Surface(1) = {1};
Point {1} In Surface {1};        // the centre is a mesh vertex

Physical Curve("boundary", 1) = arcs[];
Physical Surface("domain", 2) = {1};
