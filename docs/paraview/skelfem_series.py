"""Open a skelfem trajectory.xdmf (a run in time) in ParaView: the body warped by its displacement,
coloured by the displacement's magnitude, at the last time step (the animation controls play it).

    pvbatch skelfem_series.py results/flick/trajectory.xdmf [picture.png]
"""
import sys

from paraview.simple import (ColorBy, GetActiveViewOrCreate, GetAnimationScene, GetColorTransferFunction,
                             GetScalarBar, Render, ResetCamera, SaveScreenshot, Show, WarpByVector, Xdmf3ReaderT)

FILE = globals().get("FILE") or (sys.argv[1] if len(sys.argv) > 1 else "trajectory.xdmf")
PICTURE = sys.argv[2] if len(sys.argv) > 2 else None

series = Xdmf3ReaderT(FileName=[FILE])
times = list(series.TimestepValues) if hasattr(series.TimestepValues, "__len__") else [series.TimestepValues]
scene = GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
scene.AnimationTime = times[-1]
view = GetActiveViewOrCreate("RenderView")
view.ViewTime = times[-1]
body = WarpByVector(Input=series)
body.Vectors = ["POINTS", "displacement"]
shown = Show(body, view)
ColorBy(shown, ("POINTS", "displacement", "Magnitude"))
shown.SetScalarBarVisibility(view, True)
lut = GetColorTransferFunction("displacement")
lut.ApplyPreset("Viridis (matplotlib)", True)
bar = GetScalarBar(lut, view)
bar.Title, bar.ComponentTitle = "displacement (mm)", ""
bar.TitleColor = bar.LabelColor = [0.1, 0.1, 0.1]
bar.WindowLocation, bar.Position, bar.ScalarBarLength = "Any Location", [0.05, 0.1], 0.4
bar.RangeLabelFormat = "%-#6.3g"
if hasattr(view, "UseColorPaletteForBackground"):
    view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0
view.InteractionMode = "2D"
view.CameraPosition, view.CameraViewUp = [0, 0, 1], [0, 1, 0]
ResetCamera(view)
Render(view)
print(f"time steps: {len(times)}, last t = {times[-1]:g} s")
if PICTURE:
    SaveScreenshot(PICTURE, view, ImageResolution=[1000, 800])
