// The diamond grid of diamond-grid.geo, mode 2 (graded); parameter n (even).
mode = 2;
Include "diamond-grid.geo";
