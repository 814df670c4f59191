"""Open a skelfem solution.xdmf in ParaView the way it is meant to be seen.

The body warped by its displacement and coloured by the largest principal
stretch, the cables as tubes coloured by their tension, in a 2D (or 3D)
view with both colour legends.

    pvbatch skelfem_view.py results/finger/solution.xdmf [picture.png]

or, in ParaView's Python shell (View > Python Shell), set ``FILE`` and run
the file (``exec(open("skelfem_view.py").read())``). The filters it builds
stay in the pipeline browser to change by hand.
"""
import sys

from paraview.simple import (ColorBy, ExtractSurface, GetActiveViewOrCreate, GetColorTransferFunction,
                             GetScalarBar, Render, ResetCamera, SaveScreenshot, Show, Threshold, Tube, WarpByVector,
                             Xdmf3ReaderS)

FILE = globals().get("FILE") or (sys.argv[1] if len(sys.argv) > 1 else "solution.xdmf")
PICTURE = sys.argv[2] if len(sys.argv) > 2 else None
TUBE_RADIUS = 0.4          # mm: the cables' drawn thickness


def _between(source, field: str, lo: float, hi: float):
    """Cells whose cell field lies in [lo, hi] (skelfem's fill values: region -1 on cables, cable -1 on the body)."""
    t = Threshold(Input=source)
    t.Scalars = ["CELLS", field]
    if hasattr(t, "LowerThreshold"):          # ParaView >= 5.10
        t.LowerThreshold, t.UpperThreshold = lo, hi
    else:
        t.ThresholdRange = [lo, hi]
    return t


result = Xdmf3ReaderS(FileName=[FILE])
view = GetActiveViewOrCreate("RenderView")

body = WarpByVector(Input=_between(result, "region", 1, 1e9))
body.Vectors = ["POINTS", "displacement"]
shown = Show(body, view)
ColorBy(shown, ("CELLS", "stretch"))
shown.SetScalarBarVisibility(view, True)
stretch = GetColorTransferFunction("stretch")
stretch.ApplyPreset("Viridis (matplotlib)", True)

cables = WarpByVector(Input=_between(result, "cable", 0, 1e9))
cables.Vectors = ["POINTS", "displacement"]
tubes = Tube(Input=ExtractSurface(Input=cables))
tubes.Radius = TUBE_RADIUS
tubes.NumberofSides = 12
drawn = Show(tubes, view)
ColorBy(drawn, ("CELLS", "tension"))
drawn.SetScalarBarVisibility(view, True)
GetColorTransferFunction("tension").ApplyPreset("Inferno (matplotlib)", True)

bounds = result.GetDataInformation().GetBounds()
if abs(bounds[5] - bounds[4]) < 1e-12:        # a 2D design: look at the plane from the front
    view.InteractionMode = "2D"
    view.CameraPosition = [0, 0, 1]
    view.CameraViewUp = [0, 1, 0]
else:                                         # 3D: see the cables through the body, from a corner
    shown.Opacity = 0.35
    view.CameraPosition = [1, -1.2, 0.8]
    view.CameraFocalPoint = [0, 0, 0]
    view.CameraViewUp = [0, 0, 1]
if hasattr(view, "UseColorPaletteForBackground"):     # a white page, black legends
    view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0
for name, x in (("stretch", 0.04), ("tension", 0.76)):
    bar = GetScalarBar(GetColorTransferFunction(name), view)
    bar.TitleColor = bar.LabelColor = [0.1, 0.1, 0.1]
    bar.WindowLocation = "Any Location"
    bar.Position = [x, 0.1]
    bar.ScalarBarLength = 0.4
    bar.Title = "largest stretch" if name == "stretch" else "tension (N)"
    bar.ComponentTitle = ""
    bar.TitleFontSize, bar.LabelFontSize = 14, 12
    bar.RangeLabelFormat = "%-#6.3g"
ResetCamera(view)
Render(view)
print(f"body cells: {body.GetDataInformation().GetNumberOfCells()}, "
      f"cable segments: {cables.GetDataInformation().GetNumberOfCells()}")
if PICTURE:
    SaveScreenshot(PICTURE, view, ImageResolution=[1200, 900])
