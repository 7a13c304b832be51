// The shell scene's domain: {|x| + |y| < R}, R = 50*sqrt(2) (a square of side
// 100 turned by 45 degrees), corners S = (0,-R), E = (R,0), N = (0,R), W = (-R,0).
//
// Parameters (override with `gmsh -setnumber NAME VALUE`):
//   n > 0  : structured transfinite mesh, n subdivisions per side:
//            (n+1)^2 vertices, 2 n^2 triangles (n = 16: 289 and 512, the
//            thesis mesh). The cells are small diamonds and every cell is cut
//            by its horizontal diagonal, so the mesh is mirror-symmetric under
//            x -> -x and under y -> -y. For even n, (0,0) is a vertex.
//   n <= 0 : unstructured (Frontal-Delaunay), target size h.
//
// Physical groups: Curve "se" (1, S->E), "ne" (2, E->N), "nw" (3, N->W),
//                  "sw" (4, W->S); Surface "domain" (5).
// Triangles are counter-clockwise; no node is written that is not a triangle
// vertex. Single-threaded with a fixed seed: byte-identical output per input.

If (!Exists(n))
  n = 16;
EndIf
If (!Exists(h))
  h = 10;
EndIf

n = Round(n);
R = 50 * Sqrt(2);
If (n > 0)
  lc = R * Sqrt(2) / n;
Else
  If (h <= 0)
    Error("diamond.geo: need n > 0 or h > 0 (got n = %g, h = %g)", n, h);
    Abort;
  EndIf
  lc = h;
EndIf

Mesh.Algorithm = 6;              // Frontal-Delaunay (used when n <= 0)
Mesh.RandomSeed = 1;             // reproducible output
Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.MeshSizeFromCurvature = 0;
Mesh.MeshSizeExtendFromBoundary = 1;
Mesh.MeshSizeFromPoints = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;                // only elements of physical groups

If (n > 0)
  // Boundary points placed explicitly (gmsh's own 1-D transfinite placement
  // is off by ~1e-10 and breaks the exact symmetry), counter-clockwise from
  // S, n per side; side k, point j has coordinates built from j*R/n and
  // (n-j)*R/n only, so mirrored points are bit-for-bit equal.
  For j In {0 : n - 1}
    a = j * R / n; b = (n - j) * R / n;
    Point(1 + j) = {a, -b, 0, lc};            // se: S -> E
    Point(1 + n + j) = {b, a, 0, lc};         // ne: E -> N
    Point(1 + 2 * n + j) = {0 - a, b, 0, lc};   // nw: N -> W (0 - a: no "-0")
    Point(1 + 3 * n + j) = {-b, 0 - a, 0, lc};  // sw: W -> S
  EndFor
  m = 4 * n;
  For i In {0 : m - 1}
    Line(1 + i) = {1 + i, 1 + (i + 1) % m};
    Transfinite Curve {1 + i} = 2;
  EndFor
  Curve Loop(1) = {1 : m};                    // counter-clockwise
  Plane Surface(1) = {1};
  // Corners S, E, N, W. "Left" cuts every cell along its horizontal diagonal.
  Transfinite Surface {1} = {1, 1 + n, 1 + 2 * n, 1 + 3 * n} Left;
  se[] = {1 : n};
  ne[] = {n + 1 : 2 * n};
  nw[] = {2 * n + 1 : 3 * n};
  sw[] = {3 * n + 1 : 4 * n};
Else
  Point(1) = {0, -R, 0, lc};                  // S
  Point(2) = {R, 0, 0, lc};                   // E
  Point(3) = {0, R, 0, lc};                   // N
  Point(4) = {-R, 0, 0, lc};                  // W
  Line(1) = {1, 2};
  Line(2) = {2, 3};
  Line(3) = {3, 4};
  Line(4) = {4, 1};
  Curve Loop(1) = {1, 2, 3, 4};               // counter-clockwise
  Plane Surface(1) = {1};
  se[] = {1};
  ne[] = {2};
  nw[] = {3};
  sw[] = {4};
EndIf

Physical Curve("se", 1) = se[];
Physical Curve("ne", 2) = ne[];
Physical Curve("nw", 3) = nw[];
Physical Curve("sw", 4) = sw[];
Physical Surface("domain", 5) = {1};
