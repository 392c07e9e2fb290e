"""The periodic DEM cell (demcell): speed against YADE, tangents, relaxation, micropolar
moduli, virtual tests and the Ehlers calibration from them, cells on a GPU."""
