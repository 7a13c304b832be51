// A rectangle [x0, x1] x [y0, y1] for the shell benchmarks (clamped plate,
// Scordelis-Lo roof on the cylinder chart, partly clamped hyperbolic
// paraboloid): docs/shell-benchmarks.md.
//
// Parameters (scene `mesh.parameters`, or `gmsh -setnumber NAME VALUE`):
//   x0, x1, y0, y1 : the corners (default the unit square);
//   n  > 0 : structured, n x n cells ((n+1)^2 vertices, 2 n^2 triangles),
//            each cell cut along the diagonal from its lower-left to its
//            upper-right corner; nx, ny (if given) override n per direction;
//   n <= 0 : unstructured (Frontal-Delaunay), target size h.
//
// Physical groups: Curve "south" (1, y = y0), "east" (2, x = x1),
//                  "north" (3, y = y1), "west" (4, x = x0); Surface "domain" (5).
// Triangles are counter-clockwise; only triangle vertices are written.

If (!Exists(x0)) x0 = 0; EndIf
If (!Exists(x1)) x1 = 1; EndIf
If (!Exists(y0)) y0 = 0; EndIf
If (!Exists(y1)) y1 = 1; EndIf
If (!Exists(n)) n = 8; EndIf
If (!Exists(h)) h = 0.1; EndIf
n = Round(n);
If (!Exists(nx)) nx = n; EndIf
If (!Exists(ny)) ny = n; EndIf
nx = Round(nx); ny = Round(ny);
If (x1 <= x0 || y1 <= y0)
  Error("rectangle.geo: need x0 < x1 and y0 < y1 (got [%g, %g] x [%g, %g])", x0, x1, y0, y1);
  Abort;
EndIf
If (n <= 0 && h <= 0)
  Error("rectangle.geo: need n > 0 or h > 0 (got n = %g, h = %g)", n, h);
  Abort;
EndIf

Mesh.Algorithm = 6;
Mesh.RandomSeed = 1;
Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;

lc = h;
If (n > 0)
  lc = (x1 - x0) / nx;
EndIf
Point(1) = {x0, y0, 0, lc};
Point(2) = {x1, y0, 0, lc};
Point(3) = {x1, y1, 0, lc};
Point(4) = {x0, y1, 0, lc};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
If (n > 0)
  Transfinite Curve {1, 3} = nx + 1;
  Transfinite Curve {2, 4} = ny + 1;
  Transfinite Surface {1} = {1, 2, 3, 4} Right;
EndIf
Physical Curve("south", 1) = {1};
Physical Curve("east", 2) = {2};
Physical Curve("north", 3) = {3};
Physical Curve("west", 4) = {4};
Physical Surface("domain", 5) = {1};
