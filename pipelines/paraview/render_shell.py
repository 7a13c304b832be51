"""Renders a shell result with ParaView, two views side by side in one PNG:
left, the shell in 3D warped by its displacement u over the rigid plane
z = LEVEL (the obstacle, outlined); right, the same shell seen from above.
Both are coloured by the vertical displacement u3 with a labelled colour
bar, and the contact zone (the cells where the contact multiplier λ > 0) is
outlined in red. Heights are stretched by ZSCALE (default 10: the thesis
hypar rises 2 over a span of 141) and u is drawn at WARP times its size
(default 1, true size); both factors are written in the picture.

    xvfb-run -a pvbatch pipelines/paraview/render_shell.py FILE.xdmf OUT.png [LEVEL [ZSCALE [WARP]]]
"""
import sys

from paraview.simple import (
    AssignViewToLayout, Calculator, ColorBy, CreateLayout, CreateView, ExtractSurface, FeatureEdges,
    GetColorTransferFunction, GetScalarBar, Outline, Plane, Render, SaveScreenshot, Show,
    Text, Threshold, Transform, WarpByVector, XDMFReader,
)

path, png = sys.argv[1], sys.argv[2]
level = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
zscale = float(sys.argv[4]) if len(sys.argv) > 4 else 10.0
warp = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
WIDTH, HEIGHT = 1000, 760
RED = [0.85, 0.1, 0.1]
BLACK = [0.0, 0.0, 0.0]

shell = XDMFReader(FileNames=[path])
shell.UpdatePipeline()
# u3 as its own point array: the colour bar's title names it.
u3 = Calculator(Input=shell, ResultArrayName="u3", Function="u_Z")
deformed = WarpByVector(Input=u3, Vectors=["POINTS", "u"], ScaleFactor=warp)
deformed = Transform(Input=deformed)
deformed.Transform.Scale = [1.0, 1.0, zscale]
deformed.UpdatePipeline()
(x0, x1, y0, y1, z0, z1) = deformed.GetDataInformation().GetBounds()
(u3_min, u3_max) = deformed.PointData["u3"].GetRange()
level *= zscale

# The contact zone: the cells with λ > 0, and the outline of their union.
has_lambda = "lambda" in shell.CellData.keys()
if has_lambda:
    contact = Threshold(Input=deformed, Scalars=["CELLS", "lambda"])
    contact.LowerThreshold = 1e-12
    contact.UpperThreshold = 1e300
    contact.ThresholdMethod = "Between"
    contact_edges = FeatureEdges(Input=ExtractSurface(Input=contact))
    contact_edges.BoundaryEdges = 1
    contact_edges.FeatureEdges = 0
    contact_edges.NonManifoldEdges = 0
    contact_edges.ManifoldEdges = 0
    contact_edges.UpdatePipeline()
    n_contact = contact.GetDataInformation().GetNumberOfCells()
else:
    n_contact = 0

pad = 0.04 * max(x1 - x0, y1 - y0)
plane = Plane(Origin=[x0 - pad, y0 - pad, level], Point1=[x1 + pad, y0 - pad, level],
              Point2=[x0 - pad, y1 + pad, level])
plane_outline = Outline(Input=plane)

lut = GetColorTransferFunction("u3")
lut.ApplyPreset("Viridis (matplotlib)", True)
lut.RescaleTransferFunction(u3_min, u3_max if u3_max > u3_min else u3_min + 1e-12)


def shell_view(top):
    """A view of the shell coloured by u3, with the contact zone outlined;
    from above when `top`, else in perspective with the plane below."""
    view = CreateView("RenderView")
    view.ViewSize = [WIDTH, HEIGHT]
    view.UseColorPaletteForBackground = 0
    view.Background = [1.0, 1.0, 1.0]
    # The top view has labelled x, y axes; the 3D view its orientation triad.
    view.OrientationAxesVisibility = 0 if top else 1
    view.OrientationAxesLabelColor = BLACK
    display = Show(deformed, view)
    ColorBy(display, ("POINTS", "u3"))
    if top:
        # Unshaded: the colour reads off the bar exactly.
        display.Ambient, display.Diffuse = 1.0, 0.0
    display.SetScalarBarVisibility(view, True)
    bar = GetScalarBar(lut, view)
    bar.Title = "u3 (vertical displacement)"
    bar.ComponentTitle = ""
    bar.TitleColor = BLACK
    bar.LabelColor = BLACK
    bar.TitleFontSize = 18
    bar.LabelFontSize = 16
    bar.RangeLabelFormat = "%-#.3g"
    bar.LabelFormat = "%-#.3g"
    bar.ScalarBarLength = 0.45
    bar.WindowLocation = "Any Location"
    bar.Position = [0.86, 0.06] if top else [0.9, 0.08]
    if has_lambda and n_contact > 0:
        edges = Show(contact_edges, view)
        ColorBy(edges, None)
        edges.AmbientColor = RED
        edges.DiffuseColor = RED
        edges.LineWidth = 4.0
        edges.RenderLinesAsTubes = 1
    (xc, yc) = ((x0 + x1) / 2, (y0 + y1) / 2)
    # The first Render of a view resets its camera: rendered once before
    # the camera is set.
    Render(view)
    if top:
        view.CameraPosition = [xc, yc, z1 + 10 * (x1 - x0)]
        view.CameraFocalPoint = [xc, yc, (z0 + z1) / 2]
        view.CameraViewUp = [0.0, 1.0, 0.0]
        view.CameraParallelProjection = 1
        view.CameraParallelScale = 0.6 * max(x1 - x0, y1 - y0)
        axes = display.DataAxesGrid
        axes.GridAxesVisibility = 1
        axes.XTitle, axes.YTitle, axes.ZTitle = "x", "y", ""
        axes.AxesToLabel = 3  # the x and y axes only
        for name in ("XTitleColor", "YTitleColor", "XLabelColor", "YLabelColor", "GridColor"):
            setattr(axes, name, BLACK)
        axes.XTitleFontSize = axes.YTitleFontSize = 18
    else:
        plane_display = Show(plane, view)
        plane_display.DiffuseColor = [0.8, 0.8, 0.8]
        plane_display.Opacity = 0.5
        outline = Show(plane_outline, view)
        outline.AmbientColor = BLACK
        outline.DiffuseColor = BLACK
        outline.LineWidth = 2.0
        # An oblique camera whose distance frames the shell and the plane.
        span = max(x1 - x0, y1 - y0)
        view.CameraFocalPoint = [xc, yc, level + 0.2 * (z1 - level)]
        view.CameraPosition = [xc + 1.3 * span, yc - 1.95 * span, level + 1.2 * span]
        view.CameraViewUp = [0.0, 0.0, 1.0]
        view.CameraViewAngle = 30
    return view


def caption(view, text, where, size=18):
    label = Text(Text=text)
    shown = Show(label, view)
    shown.WindowLocation = where
    shown.Justification = "Left"
    shown.FontSize = size
    shown.Color = BLACK


side = shell_view(top=False)
top = shell_view(top=True)
factors = f"heights (z) ×{zscale:g}, displacement ×{warp:g}" + (" (true size)" if warp == 1 else "")
# ParaView's text font has no Greek letters: λ is spelled out.
contact_text = (f"red: contact zone, lambda > 0 on {n_contact} triangles" if n_contact
                else "no contact (lambda = 0 everywhere)" if has_lambda
                else "no obstacle in this scene")
caption(side, "3D view: the shell over the rigid plane z = 0 (grey, outlined)", "Upper Left Corner", 20)
caption(side, f"{factors}\n{contact_text}", "Lower Left Corner", 17)
caption(top, f"top view (x, y): u3 from {u3_min:.4g} to {u3_max:.4g}", "Upper Left Corner", 20)

layout = CreateLayout("shell")
layout.SplitHorizontal(0, 0.5)
AssignViewToLayout(view=side, layout=layout, hint=1)
AssignViewToLayout(view=top, layout=layout, hint=2)
Render(side)
Render(top)
SaveScreenshot(png, layout, ImageResolution=[2 * WIDTH, HEIGHT])
print(png)
