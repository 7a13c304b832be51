// The diamond grid of diamond-grid.geo, mode 0 (perturbed); parameter n (even).
mode = 0;
Include "diamond-grid.geo";
