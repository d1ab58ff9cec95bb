// Slender cantilever beam: length 1 m along x, square section 0.1 m x 0.1 m (y, z in [0, 0.1]).
// Clamped at x = 0 ("clamp"), loaded at x = 1 ("tip"). Units: metres.
// Mesh: python3 scripts/gen_meshes.py cantilever   (MSH 4.1 ASCII, linear tetrahedra)
SetFactory("OpenCASCADE");

L = 1.0;   // length, m
a = 0.1;   // side of the square section, m
h = 0.03;  // target element size, m

Box(1) = {0, 0, 0, L, a, a};

eps = 1e-6;
clamp() = Surface In BoundingBox{-eps, -eps, -eps, eps, a + eps, a + eps};
tip() = Surface In BoundingBox{L - eps, -eps, -eps, L + eps, a + eps, a + eps};

Physical Volume("beam", 1) = {1};
Physical Surface("clamp", 2) = {clamp()};
Physical Surface("tip", 3) = {tip()};
Physical Surface("surface", 4) = Surface{:};

Mesh.MeshSizeMin = h;
Mesh.MeshSizeMax = h;
Mesh.ElementOrder = 1;
Mesh.Algorithm3D = 1;  // Delaunay
