"""Reads a result's XDMF with ParaView's own reader and prints what ParaView
sees, as JSON: bounds, point and cell counts, and every array's range per
component. Optional warp: `vector:NAME` (Warp By Vector, scale 1) or
`scalar:NAME` (Warp By Scalar along e3, scale 1).

    pvbatch pipelines/paraview/inspect.py FILE.xdmf [vector:u | scalar:u]
"""
import json
import sys

from paraview.simple import WarpByScalar, WarpByVector, XDMFReader

path = sys.argv[1]
warp = sys.argv[2] if len(sys.argv) > 2 else None
source = XDMFReader(FileNames=[path])
source.UpdatePipeline()
if warp:
    kind, name = warp.split(":", 1)
    if kind == "vector":
        source = WarpByVector(Input=source, Vectors=["POINTS", name], ScaleFactor=1.0)
    else:
        source = WarpByScalar(Input=source, Scalars=["POINTS", name], ScaleFactor=1.0)
        source.Normal = [0.0, 0.0, 1.0]
        source.UseNormal = 1
    source.UpdatePipeline()
info = source.GetDataInformation()
arrays = {}
for location, data in (("point", source.PointData), ("cell", source.CellData)):
    for array in data:
        n = array.GetNumberOfComponents()
        arrays[array.Name] = {
            "location": location,
            "components": n,
            "ranges": [list(array.GetRange(c)) for c in range(n)],
        }
print("PARAVIEW-JSON " + json.dumps({
    "bounds": list(info.GetBounds()),
    "points": info.GetNumberOfPoints(),
    "cells": info.GetNumberOfCells(),
    "arrays": arrays,
}))
