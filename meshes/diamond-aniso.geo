// The diamond grid of diamond-grid.geo, mode 1 (aniso); parameter n (even).
mode = 1;
Include "diamond-grid.geo";
