"""Run by ParaView's pvbatch (under xvfb-run): open a legacy VTK file and print its point and
cell counts and the range of each array as JSON.

    xvfb-run -a pvbatch tests/paraview_vtk_check.py particles_0000.vtk
"""
import json
import sys

from paraview import simple

reader = simple.LegacyVTKReader(FileNames=[sys.argv[1]])
reader.UpdatePipeline()
info = reader.GetDataInformation()
arrays = {}
for data in (reader.PointData, reader.CellData):
    for name in data.keys():
        arrays[name] = list(data[name].GetRange(-1 if data[name].GetNumberOfComponents() > 1 else 0))
print("PARAVIEW_JSON " + json.dumps({"points": info.GetNumberOfPoints(), "cells": info.GetNumberOfCells(),
                                      "arrays": arrays}))
