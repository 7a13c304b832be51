// A structured grid on the shell's diamond {|x| + |y| < R}, R = 50*sqrt(2),
// for the hard cases (pipelines/scenes/hard/). Included by the wrappers
// diamond-perturbed.geo, diamond-aniso.geo and diamond-graded.geo, which set
// `mode` before including this file:
//   mode = 0 : uniform n x n grid, interior vertices moved by up to 0.2 of a
//              cell in each direction (deterministic integer hash: same mesh
//              on every machine);
//   mode = 1 : anisotropic: uniform along S->E, power-graded along S->W
//              towards both edges t = 0 and t = 1 so that the cells next to
//              the sides "se" and "nw" are 1000 times thinner than wide
//              (triangle aspect ratio 1e3);
//   mode = 2 : strongly graded: power grading (exponent 3) in both
//              directions towards the corners S and N (where the thesis'
//              obstacle touches the clamped edge), cell sizes 0.1 ... 19.
// The grid is S + s (E - S) + t (W - S), (s, t) in [0,1]^2, n cells per side
// ((n+1)^2 vertices, 2 n^2 triangles), one transfinite quadrilateral per cell
// cut along one diagonal. Triangles are counter-clockwise.
// Physical groups as diamond.geo: Curve "se" (1), "ne" (2), "nw" (3),
// "sw" (4); Surface "domain" (5).

If (!Exists(n))
  n = 16;
EndIf
If (!Exists(mode))
  mode = 0;
EndIf
n = Round(n);
If (n < 2 || n % 2 != 0)
  Error("diamond-grid.geo: n must be even and >= 2 (got n = %g)", n);
  Abort;
EndIf
R = 50 * Sqrt(2);
m = n / 2;

Mesh.MaxNumThreads1D = 1;
Mesh.MaxNumThreads2D = 1;
Mesh.RandomSeed = 1;
Mesh.ElementOrder = 1;
Mesh.SaveAll = 0;

// Grid coordinate of index k in 0..n with exponent p, graded towards both ends.
// g(k) = 0.5 (k/m)^p for k <= m, 1 - g(n - k) beyond.
pa = 1 + Log(1000) / Log(m);     // mode 1: first cell 1/(1000 n), i.e. aspect 1e3
For j In {0 : n}
  For i In {0 : n}
    s = i / n; t = j / n;
    If (mode == 1)
      If (j <= m)
        t = 0.5 * (j / m)^pa;
      Else
        t = 1 - 0.5 * ((n - j) / m)^pa;
      EndIf
    EndIf
    If (mode == 2)
      If (i <= m)
        s = 0.5 * (i / m)^3;
      Else
        s = 1 - 0.5 * ((n - i) / m)^3;
      EndIf
      If (j <= m)
        t = 0.5 * (j / m)^3;
      Else
        t = 1 - 0.5 * ((n - j) / m)^3;
      EndIf
    EndIf
    If (mode == 0 && i > 0 && i < n && j > 0 && j < n)
      s = s + 0.4 * (((i * 7919 + j * 104729) % 997) / 997 - 0.5) / n;
      t = t + 0.4 * (((i * 104729 + j * 7919 + 13) % 991) / 991 - 0.5) / n;
    EndIf
    Point(1 + i + (n + 1) * j) = {R * (s - t), R * (s + t) - R, 0, 1};
  EndFor
EndFor
// Lines: "horizontal" (along s) H(i,j) = P(i,j)->P(i+1,j), id 1 + i + n j;
// "vertical" (along t) V(i,j) = P(i,j)->P(i,j+1), id off + 1 + i + (n+1) j.
off = n * (n + 1);
For j In {0 : n}
  For i In {0 : n - 1}
    Line(1 + i + n * j) = {1 + i + (n + 1) * j, 2 + i + (n + 1) * j};
    Transfinite Curve {1 + i + n * j} = 2;
  EndFor
EndFor
For j In {0 : n - 1}
  For i In {0 : n}
    Line(off + 1 + i + (n + 1) * j) = {1 + i + (n + 1) * j, 1 + i + (n + 1) * (j + 1)};
    Transfinite Curve {off + 1 + i + (n + 1) * j} = 2;
  EndFor
EndFor
cells[] = {};
For j In {0 : n - 1}
  For i In {0 : n - 1}
    c = 1 + i + n * j;
    Curve Loop(c) = {1 + i + n * j, off + 2 + i + (n + 1) * j, -(1 + i + n * (j + 1)), -(off + 1 + i + (n + 1) * j)};
    Plane Surface(c) = {c};
    Transfinite Surface {c};
    cells[] += {c};
  EndFor
EndFor
se[] = {};
nw[] = {};
ne[] = {};
sw[] = {};
For i In {0 : n - 1}
  se[] += {1 + i};                             // t = 0: S -> E
  nw[] += {1 + i + n * n};                     // t = 1: W -> N
EndFor
For j In {0 : n - 1}
  ne[] += {off + 1 + n + (n + 1) * j};         // s = 1: E -> N
  sw[] += {off + 1 + (n + 1) * j};             // s = 0: S -> W
EndFor
Physical Curve("se", 1) = se[];
Physical Curve("ne", 2) = ne[];
Physical Curve("nw", 3) = nw[];
Physical Curve("sw", 4) = sw[];
Physical Surface("domain", 5) = cells[];
