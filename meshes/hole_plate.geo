// Quarter of a square plate with a central circular hole (symmetry on x = 0 and y = 0).
// Parameters (metres) can be overridden through ONELAB, as cosserat_fenicsx.meshes does:
//   gmsh -2 -setnumber Parameters/R 0.01 meshes/hole_plate.geo
R = DefineNumber[0.01, Name "Parameters/R"];          // hole radius
L = DefineNumber[0.2, Name "Parameters/L"];           // half side of the plate
h = DefineNumber[0.01, Name "Parameters/h"];          // element size far from the hole
h_hole = DefineNumber[0.001, Name "Parameters/h_hole"];  // element size on the hole
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, L, L};
Disk(2) = {0, 0, 0, R, R};
BooleanDifference(3) = { Surface{1}; Delete; }{ Surface{2}; Delete; };
hole() = Curve In BoundingBox{-R-1e-4*L, -R-1e-4*L, -1, R+1e-4*L, R+1e-4*L, 1};
left() = Curve In BoundingBox{-1e-4*L, R/2, -1, 1e-4*L, L*(1+1e-4), 1};
bottom() = Curve In BoundingBox{R/2, -1e-4*L, -1, L*(1+1e-4), 1e-4*L, 1};
right() = Curve In BoundingBox{L*(1-1e-4), -1e-4*L, -1, L*(1+1e-4), L*(1+1e-4), 1};
top() = Curve In BoundingBox{-1e-4*L, L*(1-1e-4), -1, L*(1+1e-4), L*(1+1e-4), 1};
Physical Surface("plate", 1) = {3};
Physical Curve("left", 1) = {left()};
Physical Curve("bottom", 2) = {bottom()};
Physical Curve("right", 3) = {right()};
Physical Curve("top", 4) = {top()};
Physical Curve("hole", 5) = {hole()};
// graded size: h_hole on the hole, growing linearly to h
Field[1] = Distance;
Field[1].CurvesList = {hole()};
Field[2] = MathEval;
Field[2].F = Sprintf("Min(%g + 0.3*(F1), %g)", h_hole, h);
Background Field = 2;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
