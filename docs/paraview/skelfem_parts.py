"""Open the STL parts skelfem fabricate writes (bones and mould halves) in ParaView, side by side.

    pvbatch skelfem_parts.py results/finger_parts [picture.png]
"""
import glob
import os
import sys

from paraview.simple import (GetActiveViewOrCreate, Render, ResetCamera, SaveScreenshot, Show,
                             STLReader, Transform)

FOLDER = globals().get("FOLDER") or (sys.argv[1] if len(sys.argv) > 1 else ".")
PICTURE = sys.argv[2] if len(sys.argv) > 2 else None
COLOURS = {"bone": [0.93, 0.90, 0.82], "mould": [0.55, 0.70, 0.90]}

view = GetActiveViewOrCreate("RenderView")
offset = 0.0
paths = sorted(glob.glob(os.path.join(FOLDER, "*.stl")))
for path in paths:
    part = STLReader(FileNames=[path])
    part.UpdatePipeline()
    lo, hi = part.GetDataInformation().GetBounds()[0:2]
    moved = Transform(Input=part)
    moved.Transform = "Transform"
    moved.Transform.Translate = [offset - lo, 0.0, 0.0]          # laid out along x, 5 mm apart
    offset += (hi - lo) + 5.0
    shown = Show(moved, view)
    shown.ColorArrayName = [None, ""]                          # one plain colour per part
    shown.DiffuseColor = COLOURS["bone" if os.path.basename(path).startswith("bone") else "mould"]
if hasattr(view, "UseColorPaletteForBackground"):
    view.UseColorPaletteForBackground = 0
view.Background = [1.0, 1.0, 1.0]
view.OrientationAxesVisibility = 0
view.CameraPosition, view.CameraFocalPoint, view.CameraViewUp = [0.15, -0.35, 1.0], [0, 0, 0], [0, 1, 0]
ResetCamera(view)
Render(view)
print(f"parts: {len(paths)}")
if PICTURE:
    SaveScreenshot(PICTURE, view, ImageResolution=[1200, 600])
