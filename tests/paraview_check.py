"""Run by ParaView's pvbatch (under xvfb-run): open an XDMF file written by
FieldWriter, print the arrays and their ranges at the last time step as JSON, and
render a PNG coloured by the requested array. dolfinx writes the mesh and every
function as separate grids of a temporal collection: the 'Xdmf3ReaderT' reader
combines them (with Xdmf3ReaderS the array-less mesh grid hides the coloured ones).

    xvfb-run -a pvbatch tests/paraview_check.py fields.xdmf out.png rotation
"""
import json
import sys

from paraview import simple

path, png, colour_by = sys.argv[1], sys.argv[2], sys.argv[3]
reader = simple.Xdmf3ReaderT(FileName=[path])
steps = reader.TimestepValues
times = [float(t) for t in steps] if hasattr(steps, "__len__") else [float(steps or 0.0)]
reader.UpdatePipeline(times[-1])
info = reader.GetDataInformation()
arrays = {}
for kind, data in (("point", reader.PointData), ("cell", reader.CellData)):
    for name in data.keys():
        array = data[name]
        arrays[name] = {"kind": kind, "components": array.GetNumberOfComponents(),
                        "range": [list(array.GetRange(i)) for i in range(array.GetNumberOfComponents())],
                        "magnitude_range": list(array.GetRange(-1))}
view = simple.GetActiveViewOrCreate("RenderView")
view.ViewSize = [800, 600]
scene = simple.GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
scene.AnimationTime = times[-1]
display = simple.Show(reader, view)
simple.ColorBy(display, ("POINTS" if arrays[colour_by]["kind"] == "point" else "CELLS", colour_by))
# colour through vertex colours: texture-mapped scalars come out blank in software GL
display.InterpolateScalarsBeforeMapping = 0
display.RescaleTransferFunctionToDataRange(True, False)
display.SetScalarBarVisibility(view, True)
view.ResetCamera()
simple.Render(view)
simple.SaveScreenshot(png, view, ImageResolution=[800, 600])
print("PARAVIEW_JSON " + json.dumps({"times": times, "cells": info.GetNumberOfCells(),
                                      "points": info.GetNumberOfPoints(), "arrays": arrays}))
