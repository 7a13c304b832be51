// Cook's tapered panel (Cook, Improved two-dimensional finite element,
// J. Struct. Div. ASCE 100 (1974)): the quadrilateral (0, 0), (48, 44),
// (48, 60), (0, 44), clamped on x = 0 and sheared on x = 48
// (docs/shell-benchmarks.md).
//
// Parameters (scene `mesh.parameters`, or `gmsh -setnumber NAME VALUE`):
//   n > 0 : structured, n x n cells, each cut along its diagonal from the
//           lower-left to the upper-right corner.
//
// Physical groups: Curve "south" (1, lower slanted edge), "east" (2, x = 48),
//                  "north" (3, upper slanted edge), "west" (4, x = 0);
//                  Surface "domain" (5).
// Triangles are counter-clockwise; only triangle vertices are written.

If (!Exists(n)) n = 8; EndIf
n = Round(n);
If (n <= 0)
  Error("cook.geo: need n > 0 (got n = %g)", n);
  Abort;
EndIf

Mesh.Algorithm = 6;
Mesh.RandomSeed = 1;
Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;

Point(1) = {0, 0, 0, 1};
Point(2) = {48, 44, 0, 1};
Point(3) = {48, 60, 0, 1};
Point(4) = {0, 44, 0, 1};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Transfinite Curve {1, 2, 3, 4} = n + 1;
Transfinite Surface {1} = {1, 2, 3, 4} Right;
Physical Curve("south", 1) = {1};
Physical Curve("east", 2) = {2};
Physical Curve("north", 3) = {3};
Physical Curve("west", 4) = {4};
Physical Surface("domain", 5) = {1};
