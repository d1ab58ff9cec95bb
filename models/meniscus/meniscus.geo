// Meniscus-like crescent wedge (human medial meniscus scale). Units: millimetres.
//
// Tibial plateau = plane z = 0, z points to the femur. The body is the revolution about the
// z-axis, over an arc of Arc degrees centred on the +x axis (opening towards -x), of the wedge
// cross-section in the (r, z) half-plane:
//
//   (Ro, Ho) +                 outer rim (peripheral, attached to the capsule): thick
//            |\   upper (femoral) surface, sloping down to the inner edge
//            | \_______
//            |         \_____ + (Ri, Hi)  inner edge: thin (not 0: a knife edge makes slivers)
//            |               |
//   (Ro, 0)  +---------------+ (Ri, 0)    lower (tibial) surface, flat
//
// The two end faces (the horns, at +-Arc/2) attach to the tibial plateau: fixed.
// "probe": a ~3 x 3 mm patch of the upper surface at the middle of the arc (angle 0), imprinted
// on the upper face with BooleanFragments, where a surgical probe presses.
//
// Mesh: python3 scripts/gen_meniscus.py   (MSH 4.1 ASCII, linear tetrahedra)
SetFactory("OpenCASCADE");
Geometry.OCCBoundsUseStl = 1;  // tight bounding boxes for the surface selections below

Ri = 14.0;    // inner radius, mm
Ro = 25.0;    // outer radius, mm (radial width 11 mm, mean radius 19.5 mm)
Hi = 1.0;     // thickness at the inner edge, mm
Ho = 7.0;     // thickness at the outer rim, mm
Arc = 190;    // arc, degrees
h = 1.6;      // target element size, mm
hp = 0.8;     // element size on the probe patch, mm

Rp = 20.0;    // radius of the probe patch centre, mm
Wp = 3.0;     // probe patch width (radial) and length (along the arc), mm

// Cross-section in the plane y = 0 (x = r), revolved from -Arc/2 to +Arc/2.
Point(1) = {Ri, 0, 0};
Point(2) = {Ro, 0, 0};
Point(3) = {Ro, 0, Ho};
Point(4) = {Ri, 0, Hi};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Rotate {{0, 0, 1}, {0, 0, 0}, -Arc / 2 * Pi / 180} { Surface{1}; }
body[] = Extrude {{0, 0, 1}, {0, 0, 0}, Arc * Pi / 180} { Surface{1}; };
// body[1] is the volume.

// Probe patch: the piece of the upper cone between r = Rp -+ Wp/2 and angles -+ dphi/2, with
// dphi = Wp / Rp (arc length Wp at the patch centre). Same cone as the upper face, so the
// fragment operation imprints it on that face.
zup = Hi + (Ho - Hi) * (Rp - Ri) / (Ro - Ri);
dz = (Ho - Hi) / (Ro - Ri) * Wp / 2;
dphi = Wp / Rp;
Point(101) = {Rp - Wp / 2, 0, zup - dz};
Point(102) = {Rp + Wp / 2, 0, zup + dz};
Line(101) = {101, 102};
Rotate {{0, 0, 1}, {0, 0, 0}, -dphi / 2} { Line{101}; }
patch[] = Extrude {{0, 0, 1}, {0, 0, 0}, dphi} { Line{101}; };
// patch[1] is the surface.

BooleanFragments{ Volume{body[1]}; Delete; }{ Surface{patch[1]}; Delete; }

// Selections by bounding box (mm). A selected entity's box must lie inside the given box.
e = 0.05;
big = 100;
a = Arc / 2 * Pi / 180;
// Horn faces: planes at angles -+a, r in [Ri, Ro], z in [0, Ho].
xa = Ri * Cos(a); xb = Ro * Cos(a);
posterior() = Surface In BoundingBox{
  Min(xa, xb) - e, -Ro * Sin(a) - e, -e, Max(xa, xb) + e, -Ri * Sin(a) + e, Ho + e};
anterior() = Surface In BoundingBox{
  Min(xa, xb) - e, Ri * Sin(a) - e, -e, Max(xa, xb) + e, Ro * Sin(a) + e, Ho + e};
probe() = Surface In BoundingBox{
  (Rp - Wp / 2) * Cos(dphi / 2) - e, -(Rp + Wp / 2) * Sin(dphi / 2) - e, zup - dz - e,
  Rp + Wp / 2 + e, (Rp + Wp / 2) * Sin(dphi / 2) + e, zup + dz + e};
// Upper surface (with the patch): the only faces lying entirely in z >= Hi.
upper() = Surface In BoundingBox{-big, -big, Hi - e, big, big, Ho + e};
// Lower (tibial) surface z = 0: not used by scene.toml; for variants resting on the plateau.
lower() = Surface In BoundingBox{-big, -big, -e, big, big, e};

If (#posterior() != 1 || #anterior() != 1 || #probe() != 1 || #upper() != 2 || #lower() != 1)
  Error("meniscus.geo: surface selection failed: posterior %g, anterior %g, probe %g, upper %g, lower %g",
        #posterior(), #anterior(), #probe(), #upper(), #lower());
EndIf

Physical Volume("meniscus", 1) = Volume{:};
Physical Surface("anterior_horn", 2) = {anterior()};
Physical Surface("posterior_horn", 3) = {posterior()};
Physical Surface("probe", 4) = {probe()};
Physical Surface("upper", 5) = {upper()};
Physical Surface("surface", 6) = Surface{:};
Physical Surface("lower", 7) = {lower()};

Mesh.MeshSizeMin = hp;
Mesh.MeshSizeMax = h;
MeshSize{ PointsOf{ Surface{probe()}; } } = hp;
Mesh.MeshSizeFromCurvature = 0;
Mesh.ElementOrder = 1;
Mesh.Algorithm3D = 1;  // Delaunay
Mesh.SaveAll = 0;      // write the physical groups only
