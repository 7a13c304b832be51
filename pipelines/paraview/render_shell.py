"""Renders a shell result in 3D with ParaView: the shell warped by its
displacement u, coloured by the contact pressure λ (zero off the contact
zone), above the rigid plane z = LEVEL, to a PNG. Heights are stretched by
ZSCALE (default 10: the thesis hypar rises 2 over a span of 141).

    xvfb-run -a pvbatch pipelines/paraview/render_shell.py FILE.xdmf OUT.png [LEVEL [ZSCALE]]
"""
import sys

from paraview.simple import (
    ColorBy, GetActiveViewOrCreate, GetColorTransferFunction, GetScalarBar,
    Plane, ResetCamera, SaveScreenshot, Show, Transform, WarpByVector, XDMFReader,
)

path, png = sys.argv[1], sys.argv[2]
level = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
zscale = float(sys.argv[4]) if len(sys.argv) > 4 else 10.0
shell = XDMFReader(FileNames=[path])
shell.UpdatePipeline()
deformed = WarpByVector(Input=shell, Vectors=["POINTS", "u"], ScaleFactor=1.0)
deformed = Transform(Input=deformed)
deformed.Transform.Scale = [1.0, 1.0, zscale]
deformed.UpdatePipeline()
(x0, x1, y0, y1, _, _) = deformed.GetDataInformation().GetBounds()
level *= zscale
view = GetActiveViewOrCreate("RenderView")
view.ViewSize = [1200, 900]
view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 1
pad = 0.1 * max(x1 - x0, y1 - y0)
plane = Plane(Origin=[x0 - pad, y0 - pad, level], Point1=[x1 + pad, y0 - pad, level],
              Point2=[x0 - pad, y1 + pad, level])
plane_display = Show(plane, view)
plane_display.DiffuseColor = [0.75, 0.75, 0.75]
plane_display.Opacity = 0.6
display = Show(deformed, view)
ColorBy(display, ("CELLS", "lambda"))
display.SetScalarBarVisibility(view, True)
lut = GetColorTransferFunction("lambda")
lut.ApplyPreset("Cool to Warm", True)
bar = GetScalarBar(lut, view)
bar.Title = "contact pressure"
bar.TitleColor = [0.0, 0.0, 0.0]
bar.LabelColor = [0.0, 0.0, 0.0]
view.CameraPosition = [x1 + 0.6 * (x1 - x0), y0 - 0.9 * (y1 - y0), level + 0.5 * (x1 - x0)]
view.CameraFocalPoint = [(x0 + x1) / 2, (y0 + y1) / 2, level]
view.CameraViewUp = [0.0, 0.0, 1.0]
ResetCamera()
view.CameraParallelScale = 0.5 * (x1 - x0)
SaveScreenshot(png, view, ImageResolution=[1200, 900])
print(png)
