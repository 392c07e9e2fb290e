"""Run by ParaView's pvbatch (under xvfb-run): load the footing demo's ParaView Python state
(paraview_footing.py in its output directory), print the time steps, point counts and arrays of
the continuum and of the grains as JSON, and render the last time to a PNG.

    xvfb-run -a pvbatch tests/paraview_footing_check.py OUT/paraview_footing.py render.png
"""
import json
import sys

from paraview import simple

state, png = sys.argv[1], sys.argv[2]
namespace = {"__file__": state, "__name__": "__paraview_state__"}
with open(state) as f:
    exec(compile(f.read(), state, "exec"), namespace)
out = {}
for name in ("continuum", "grains"):
    source = simple.FindSource(name)
    source.UpdatePipeline(max(source.TimestepValues) if len(source.TimestepValues) else 0.0)
    info = source.GetDataInformation()
    out[name] = {"times": list(source.TimestepValues), "points": info.GetNumberOfPoints(),
                 "arrays": sorted(source.PointData.keys())}
view = simple.GetActiveView()
view.ViewSize = [900, 500]
simple.SaveScreenshot(png, view)
print("PARAVIEW_JSON " + json.dumps(out))
