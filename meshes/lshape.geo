// L-shaped domain (-1,1)^2 minus [0,1]x[-1,0], re-entrant corner at (0,0)
// (interior angle 3*Pi/2), for the membrane's corner-singularity case
// (pipelines/scenes/lshape*.toml, docs/formulation.md §8).
//
// Parameters (override with `gmsh -setnumber NAME VALUE`):
//   n > 0  : structured: each of the three unit squares [-1,0]x[0,1],
//            [-1,0]x[-1,0], [0,1]x[0,1] is an n x n grid of cells cut along
//            one diagonal: 3(n+1)^2 - 2(n+1) vertices, 6 n^2 triangles, h = Sqrt(2)/n.
//   n <= 0 : unstructured (Delaunay), target size h.
//
// Physical groups: Curve "boundary" (tag 1) = the whole boundary,
//                  Surface "domain" (tag 2).
// The corner (0,0) is always a vertex. Triangles are counter-clockwise; no
// node is written that is not a triangle vertex. Single-threaded with a
// fixed seed: byte-identical output per input.

If (!Exists(n))
  n = 8;
EndIf
If (!Exists(h))
  h = 0.1;
EndIf

n = Round(n);
If (n > 0)
  lc = 1 / n;
Else
  If (h <= 0)
    Error("lshape.geo: need n > 0 or h > 0 (got n = %g, h = %g)", n, h);
    Abort;
  EndIf
  lc = h;
EndIf

Mesh.Algorithm = 5;              // Delaunay (used when n <= 0): Frontal-Delaunay made
                                 // a flat triangle at the corner under strong grading
Mesh.RandomSeed = 1;             // reproducible output
Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.MeshSizeFromCurvature = 0;
Mesh.MeshSizeExtendFromBoundary = 1;
Mesh.MeshSizeFromPoints = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;                // only elements of physical groups

Point(1) = {0, 0, 0, lc};        // the re-entrant corner
Point(2) = {1, 0, 0, lc};
Point(3) = {1, 1, 0, lc};
Point(4) = {0, 1, 0, lc};
Point(5) = {-1, 1, 0, lc};
Point(6) = {-1, 0, 0, lc};
Point(7) = {-1, -1, 0, lc};
Point(8) = {0, -1, 0, lc};

If (n > 0)
  // Three squares sharing the segments corner-N (0,0)-(0,1) and corner-W (0,0)-(-1,0).
  Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};   // NE square
  Line(5) = {4, 5}; Line(6) = {5, 6}; Line(7) = {6, 1};                     // NW square (with 4)
  Line(8) = {6, 7}; Line(9) = {7, 8}; Line(10) = {8, 1};                    // SW square (with 7)
  Transfinite Curve {1 : 10} = n + 1;
  Curve Loop(1) = {1, 2, 3, 4};
  Plane Surface(1) = {1};
  Curve Loop(2) = {-4, 5, 6, 7};
  Plane Surface(2) = {2};
  Curve Loop(3) = {-7, 8, 9, 10};
  Plane Surface(3) = {3};
  Transfinite Surface {1} = {1, 2, 3, 4} Left;
  Transfinite Surface {2} = {1, 4, 5, 6} Left;
  Transfinite Surface {3} = {1, 6, 7, 8} Left;
  surfaces[] = {1, 2, 3};
  boundary[] = {1, 2, 3, 5, 6, 8, 9, 10};
Else
  For i In {1 : 8}
    Line(i) = {i, i % 8 + 1};
  EndFor
  Curve Loop(1) = {1 : 8};       // counter-clockwise
  Plane Surface(1) = {1};
  surfaces[] = {1};
  boundary[] = {1 : 8};
EndIf

Physical Curve("boundary", 1) = boundary[];
Physical Surface("domain", 2) = surfaces[];
