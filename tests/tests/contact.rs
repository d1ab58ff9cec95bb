//! The contact step against the full-order contact reference (docs/contact.md): a 2 mm sphere
//! pressed into the meniscus's femoral surface, held, and lifted off, open loop; the reduced
//! model's tool force against the full-order linear FEM with the same tool and contact law.

use std::path::Path;

use crokf_compile::compile::{compile, CompileOptions};
use crokf_compile::full_order::FullOrder;
use crokf_compile::mesh::procedural::{box_mesh, write_msh22};
use crokf_compile::timer::StageTimer;
use crokf_runtime::{ContactStatus, Estimator, RuntimeError};
use crokf_verify::contact::ContactReference;

#[path = "../../runtime/tests/support/cdylib.rs"]
mod cdylib;
#[path = "../../runtime/tests/support/counting_alloc.rs"]
mod counting_alloc;

fn scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/scene_touch.toml")
}

/// The region node nearest `target` (m): its index, rest position and outward normal.
fn nearest_node(
    region: &crokf_formats::ContactRegion,
    target: [f64; 3],
) -> (usize, [f64; 3], [f64; 3]) {
    let (node, _) = (0..region.len())
        .map(|i| {
            let p = &region.rest_positions.data[3 * i..3 * i + 3];
            let d: f64 = (0..3).map(|c| (p[c] - target[c]).powi(2)).sum();
            (i, d)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("nodes");
    let p = &region.rest_positions.data[3 * node..3 * node + 3];
    let n = &region.normals.data[3 * node..3 * node + 3];
    (node, [p[0], p[1], p[2]], [n[0], n[1], n[2]])
}

fn norm(v: [f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn relative(got: [f64; 3], want: [f64; 3]) -> f64 {
    norm([got[0] - want[0], got[1] - want[1], got[2] - want[2]]) / norm(want).max(1e-300)
}

/// A compiled scene with a contact region, its full-order model, and a step's empty inputs,
/// measurements and full-order loads.
struct Touch {
    model: crokf_formats::Model,
    full: FullOrder,
    inputs: Vec<f64>,
    none: Vec<Option<f64>>,
    f_ext: Vec<f64>,
}

impl Touch {
    fn new(scene: &Path) -> Self {
        let model = compile(scene, &CompileOptions::default())
            .expect("compile")
            .model;
        assert!(
            model.contact.is_some(),
            "the scene declares a contact region"
        );
        let full = FullOrder::build(scene, &mut StageTimer::default()).expect("full order");
        Touch {
            inputs: vec![0.0; model.inputs.len()],
            none: vec![None; model.measurements.len()],
            f_ext: vec![0.0; full.fem.dof_count()],
            model,
            full,
        }
    }

    fn radius(&self) -> f64 {
        self.model.contact.as_ref().map_or(0.0, |c| c.tool_radius)
    }

    /// The tool's centre pressed `d` (m) along the normal of the region node nearest `target`.
    fn along_normal(&self, target: [f64; 3]) -> impl Fn(f64) -> [f64; 3] {
        let region = self.model.contact.as_ref().expect("contact region");
        let (_, p, n) = nearest_node(region, target);
        let radius = region.tool_radius;
        move |d: f64| [0, 1, 2].map(|i| p[i] + n[i] * (radius - d))
    }
}

/// What a staged press measured.
struct Press {
    /// Worst relative error of the reduced model's settled force against the full order's.
    worst: f64,
    /// Most region nodes pressing in the full-order solve.
    most_nodes: usize,
    /// (depth m, reduced force N, full-order force N) per stage.
    stages: Vec<(f64, f64, f64)>,
}

/// Force against depth: the sphere pressed along the normal of the region node nearest
/// `target` (m) in stages to each of `depths` (m), each ramped over 50 steps and held until
/// the force changes by less than 10⁻⁹ of itself a step; the reduced model's settled tool force against the full-order static
/// contact solve at the same tool position (the full-order FEM's K, its own solver).
fn press(scene: &Path, target: [f64; 3], depths: &[f64]) -> Press {
    let touch = Touch::new(scene);
    let Touch {
        model,
        full,
        inputs,
        none,
        f_ext,
    } = &touch;
    let mut reference = ContactReference::quasi_static(full).expect("reference");
    let mut est = Estimator::new(model).expect("estimator");
    let at = touch.along_normal(target);
    let mut out = Press {
        worst: 0.0,
        most_nodes: 0,
        stages: Vec::new(),
    };
    let mut previous = 0.0;
    for &d in depths {
        // Ramp over 50 steps, then hold until the force changes by < 1e-9 of itself per step
        // over 20 steps (at most 50 000 steps).
        let mut last = [0.0; 3];
        let mut quiet = 0;
        let mut drift = f64::INFINITY;
        for k in 1..=50_000 {
            let dk = previous + (d - previous) * (k.min(50) as f64 / 50.0);
            est.step_with_tools(&[at(dk)], inputs, none).expect("step");
            let f = est.tool_contact(0).expect("tool").force;
            drift = relative(f, last);
            last = f;
            quiet = if k > 50 && drift < 1e-9 { quiet + 1 } else { 0 };
            if quiet == 20 {
                break;
            }
        }
        previous = d;
        let tool = *est.tool_contact(0).expect("tool");
        let want = reference
            .solve_static(at(d), f_ext)
            .expect("static reference");
        let err = relative(tool.force, want.force);
        eprintln!(
            "{}: depth {:.3e} m: reduced {:.6} N ({} nodes, {:?}, drift {drift:.1e}), full order {:.6} N ({} nodes): {:.2e}",
            scene.display(),
            d,
            norm(tool.force),
            tool.active,
            tool.status,
            norm(want.force),
            want.active,
            err
        );
        assert_eq!(
            tool.status,
            ContactStatus::Touching,
            "a settled press touches"
        );
        assert!(
            quiet == 20,
            "settled (the last step changed the force by {drift})"
        );
        out.worst = out.worst.max(err);
        out.most_nodes = out.most_nodes.max(want.active);
        out.stages.push((d, norm(tool.force), norm(want.force)));
    }
    out
}

/// A press in time: the sphere driven along the normal of the region node nearest `target`
/// to `depth` (m) over `ramp` steps (a half cosine: it meets the surface at rest), held `hold`
/// steps, lifted over `ramp` steps; the reduced
/// model's tool force at every step against the full-order dynamic reference (Wilson-θ at the
/// scene's Δt, gap at the θ-point). Returns (largest force error over the run / largest
/// full-order force, largest full-order force N, pressing nodes at most).
fn press_in_time(
    scene: &Path,
    target: [f64; 3],
    depth: f64,
    ramp: usize,
    hold: usize,
) -> (f64, f64, usize) {
    let touch = Touch::new(scene);
    let Touch {
        model,
        full,
        inputs,
        none,
        f_ext,
    } = &touch;
    let mut reference = ContactReference::new(full).expect("reference");
    let mut est = Estimator::new(model).expect("estimator");
    let at = touch.along_normal(target);
    let steps = 2 * ramp + hold;
    let (mut worst, mut peak, mut most) = (0.0f64, 0.0f64, 0usize);
    for k in 1..=steps {
        // Smooth in and out (zero tool speed where the press starts, holds and ends).
        let smooth = |s: f64| 0.5 - 0.5 * (std::f64::consts::PI * s).cos();
        let d = depth
            * if k <= ramp {
                smooth(k as f64 / ramp as f64)
            } else if k <= ramp + hold {
                1.0
            } else {
                smooth((steps - k) as f64 / ramp as f64)
            };
        est.step_with_tools(&[at(d)], inputs, none).expect("step");
        let got = est.tool_contact(0).expect("tool").force;
        let want = reference.step(at(d), f_ext).expect("reference step");
        let diff = [0, 1, 2].map(|c| got[c] - want.force[c]);
        worst = worst.max(norm(diff));
        peak = peak.max(norm(want.force));
        most = most.max(want.active);
    }
    (worst / peak.max(1e-300), peak, most)
}

/// The meniscus's femoral surface at mid-arc (the seed's scene): its horns alone hold it, so
/// the sphere mostly bends the whole crescent and only one or two nodes touch.
#[test]
fn a_pressed_sphere_gets_the_full_order_force_on_the_meniscus() {
    let depths: Vec<f64> = (1..=6).map(|k| 2.0e-4 * k as f64).collect();
    let out = press(&scene(), [0.020, 0.0, 0.00427], &depths);
    eprintln!("meniscus: worst relative force error {:.2e}", out.worst);
    assert!(
        out.worst < 1e-4,
        "settled force within 1e-4 of the full order's ({})",
        out.worst
    );
}

/// A block on a rigid floor (16 × 16 × 8 mm, 0.8 mm cells, soft tissue) pressed at the top
/// centre by a 4 mm sphere until ≥ 7 nodes touch; Hertz's F = 4/3 E* √R d^1.5 is printed beside
/// (no target: a node-on-sphere law on a 0.8 mm mesh under-counts the contact patch).
#[test]
fn a_pressed_sphere_gets_the_full_order_force_on_a_block() {
    let (dir, scene) = block_scene("block");
    let depths: Vec<f64> = (1..=6).map(|k| 1.0e-4 * k as f64).collect();
    let out = press(&scene, [0.008, 0.008, 0.008], &depths);
    std::fs::remove_dir_all(&dir).ok();
    let (e, nu, r) = (5.0e5f64, 0.45f64, 4.0e-3f64);
    let e_star = e / (1.0 - nu * nu);
    for &(d, got, want) in &out.stages {
        let hertz = 4.0 / 3.0 * e_star * r.sqrt() * d.powf(1.5);
        eprintln!(
            "block: depth {:.1} mm: reduced {got:.4} N, full order {want:.4} N, Hertz {hertz:.4} N",
            d * 1e3
        );
    }
    eprintln!(
        "block: worst relative force error {:.2e}, {} nodes at the deepest",
        out.worst, out.most_nodes
    );
    assert!(
        out.most_nodes >= 7,
        "the deepest press touches ≥ 7 nodes ({})",
        out.most_nodes
    );
    assert!(
        out.worst < 1e-4,
        "settled force within 1e-4 of the full order's ({})",
        out.worst
    );
}

/// The held-out kidney (models/bodies, not used while building the contact step) with a
/// region around its loaded pole and a 10 mm sphere.
#[test]
fn a_pressed_sphere_gets_the_full_order_force_on_the_kidney() {
    let (dir, scene) = kidney_scene("press");
    let depths: Vec<f64> = (1..=5).map(|k| 1.0e-3 * k as f64).collect();
    let out = press(&scene, [0.07, 0.025, 0.0], &depths);
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "kidney: worst relative force error {:.2e}, {} nodes at the deepest",
        out.worst, out.most_nodes
    );
    assert!(
        out.worst < 1e-4,
        "settled force within 1e-4 of the full order's ({})",
        out.worst
    );
}

const BLOCK_SCENE: &str = r#"
[mesh]
file = "block.msh"
units = "mm"

[[material]]
group = "body"
young_modulus = 5.0e5
poisson_ratio = 0.45
density = 1100.0

[damping]
alpha = 5.0
beta = 1.0e-3

[[fixed]]
select = [{ box = { min = [-1.0, -1.0, -0.1], max = [17.0, 17.0, 0.1] }, nodes = "all" }]

[[load]]
name = "side"
select = [{ box = { min = [15.9, 6.0, 2.0], max = [16.1, 10.0, 6.0] }, nodes = "boundary" }]
distribution = "area"
range = 0.5

[[sensor]]
name = "corner"
position = [16.0, 16.0, 8.0]
noise_std = 2.0e-4

[[contact]]
name = "top"
select = [{ box = { min = [3.0, 3.0, 7.9], max = [13.0, 13.0, 8.1] }, nodes = "boundary" }]
radius = 4.0
max_force = 20.0

[time]
dt = 0.001
theta = 1.4
"#;

const KIDNEY_CONTACT: &str = r#"
[[contact]]
name = "pole"
select = [{ sphere = { center = [0.058, 0.025, 0.0], radius = 0.02 }, nodes = "boundary" }]
radius = 0.01
max_force = 5.0
"#;

#[test]
fn a_press_pushes_back_within_its_bound_and_leaving_gives_zero_at_once() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let region = model.contact.as_ref().expect("contact region");
    let p = &region.rest_positions.data[0..3];
    let n = &region.normals.data[0..3];
    let radius = region.tool_radius;
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let at = |d: f64| [0, 1, 2].map(|i| p[i] + n[i] * (radius - d));
    for k in 1..=200 {
        est.step_with_tools(&[at(5e-4 * k as f64 / 200.0)], &inputs, &none)
            .expect("step");
        let t = est.tool_contact(0).expect("tool");
        let mag = t.force.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(mag.is_finite() && mag <= region.max_force * (1.0 + 1e-12));
    }
    let t = *est.tool_contact(0).expect("tool");
    // Pressed along the outward normal: the body pushes the tool outward.
    let along: f64 = (0..3).map(|i| t.force[i] * n[i]).sum();
    assert!(along > 0.0, "the force pushes the tool out ({:?})", t.force);
    assert!(t.active >= 1 && t.status != ContactStatus::Free);
    // Far away at once: no force at once.
    est.step_with_tools(&[at(-0.01)], &inputs, &none)
        .expect("step");
    let t = est.tool_contact(0).expect("tool");
    assert_eq!(t.force, [0.0; 3]);
    assert_eq!(t.status, ContactStatus::Free);
    assert!(est.contact_points().is_empty());
}

#[test]
fn bad_tools_are_refused_and_change_nothing() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let mut est = Estimator::new(&compiled.model).expect("estimator");
    let inputs = vec![0.0; compiled.model.inputs.len()];
    let none = vec![None; compiled.model.measurements.len()];
    let before = est.state().to_vec();
    let err = est
        .step_with_tools(&[[f64::NAN, 0.0, 0.0]], &inputs, &none)
        .unwrap_err();
    assert!(
        matches!(err, RuntimeError::NonFiniteTool { tool: 0, .. }),
        "{err}"
    );
    let err = est
        .step_with_tools(&[[0.0; 3]; 3], &inputs, &none)
        .unwrap_err();
    assert!(
        matches!(err, RuntimeError::TooManyTools { given: 3, .. }),
        "{err}"
    );
    assert_eq!(est.state(), &before[..]);
    assert_eq!(est.step_index(), 0);
}

/// The meniscus pressed 1 mm in 100 steps (0.1 s), held 100 and lifted: the force over time
/// against the full-order dynamics.
#[test]
fn a_press_in_time_follows_the_full_order_dynamics_on_the_meniscus() {
    let (err, peak, most) = press_in_time(&scene(), [0.020, 0.0, 0.00427], 1.0e-3, 100, 100);
    eprintln!(
        "meniscus in time: largest force error {err:.2e} of the peak {peak:.4} N ({most} nodes)"
    );
    assert!(
        err < 0.02,
        "force within 2 % of the full order's peak over the run ({err})"
    );
}

/// The block pressed 0.5 mm in 100 steps (0.1 s), held 100 and lifted.
#[test]
fn a_press_in_time_follows_the_full_order_dynamics_on_a_block() {
    let (dir, scene) = block_scene("block-time");
    let (err, peak, most) = press_in_time(&scene, [0.008, 0.008, 0.008], 5.0e-4, 100, 100);
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "block in time: largest force error {err:.2e} of the peak {peak:.4} N ({most} nodes)"
    );
    assert!(
        err < 0.02,
        "force within 2 % of the full order's peak over the run ({err})"
    );
}

/// The block's scene written with its mesh to a fresh temporary folder (removed by the caller).
/// The held-out kidney's linear scene with [`KIDNEY_CONTACT`], in a scratch folder.
fn kidney_scene(tag: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let bodies = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/bodies/kidney");
    let text = std::fs::read_to_string(bodies.join("scene_linear.toml")).expect("kidney scene");
    let mesh = bodies.join("kidney.msh");
    let text = text.replace(
        "file = \"kidney.msh\"",
        &format!("file = {:?}", mesh.display().to_string()),
    ) + KIDNEY_CONTACT;
    let dir =
        std::env::temp_dir().join(format!("crokf-contact-kidney-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, text).expect("write scene");
    (dir, scene)
}

fn block_scene(tag: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!("crokf-contact-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    write_msh22(
        &box_mesh([20, 20, 10], [16.0, 16.0, 8.0]),
        &dir.join("block.msh"),
    )
    .expect("write mesh");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, BLOCK_SCENE).expect("write scene");
    (dir, scene)
}

/// The sphere pressed 0.4 mm into the block, then slid 6 mm along x (7.5 cells) over 3000
/// steps at that depth, slowly enough to stay quasi-static: the force every 25 steps against
/// the full-order static solve at the same tool position, and the change of the force from one
/// step to the next (no pops at element edges).
#[test]
fn a_sliding_sphere_gets_the_full_order_force_without_pops() {
    let (dir, scene) = block_scene("slide");
    let touch = Touch::new(&scene);
    std::fs::remove_dir_all(&dir).ok();
    let Touch {
        model,
        full,
        inputs,
        none,
        f_ext,
    } = &touch;
    let mut reference = ContactReference::quasi_static(full).expect("reference");
    let radius = touch.radius();
    let mut est = Estimator::new(model).expect("estimator");
    let depth = 4.0e-4;
    let top = 0.008;
    let at = |x: f64, d: f64| [x, 0.008, top + radius - d];
    let (x0, x1) = (0.005, 0.011);
    // Press at x0 and let it settle.
    for k in 1..=2000 {
        let d = depth * (k as f64 / 200.0).min(1.0);
        est.step_with_tools(&[at(x0, d)], inputs, none)
            .expect("press");
    }
    reference
        .solve_static(at(x0, depth), f_ext)
        .expect("reference press");
    let steps = 3000;
    let (mut worst, mut jump, mut most) = (0.0f64, 0.0f64, 0usize);
    let mut last = est.tool_contact(0).expect("tool").force;
    for k in 1..=steps {
        let x = x0 + (x1 - x0) * k as f64 / steps as f64;
        est.step_with_tools(&[at(x, depth)], inputs, none)
            .expect("slide");
        let tool = *est.tool_contact(0).expect("tool");
        assert_eq!(tool.status, ContactStatus::Touching, "step {k}");
        jump = jump.max(norm([0, 1, 2].map(|c| tool.force[c] - last[c])) / norm(tool.force));
        last = tool.force;
        most = most.max(tool.active);
        if k % 25 == 0 {
            let want = reference
                .solve_static(at(x, depth), f_ext)
                .expect("reference");
            worst = worst.max(relative(tool.force, want.force));
        }
    }
    eprintln!(
        "block slide: force within {worst:.2e} of the full order's, largest step-to-step change \
         {jump:.2e} of the force, up to {most} nodes"
    );
    assert!(
        worst < 0.03,
        "sliding force within 3 % of the full order's ({worst})"
    );
    assert!(
        jump < 0.01,
        "no step changes the force by 1 % or more ({jump})"
    );
}

/// What a grasp-and-drag measured.
struct Drag {
    /// Worst relative error of the tool force against the full-order static grasp, along the
    /// drag (every 25 steps) and settled at its end.
    moving: f64,
    settled: f64,
    /// The settled force, N.
    force: [f64; 3],
}

/// The sphere pressed `depth` (m) along the normal of the region node nearest `target`,
/// settled, then grasping the node nearest its centre and dragged by `drag` (m) over `steps`
/// steps, slowly enough to stay quasi-static, then held until settled: the tool force against
/// the full-order static solve with the same node held at the same point.
fn grasp_and_drag(
    scene: &Path,
    target: [f64; 3],
    depth: f64,
    drag: [f64; 3],
    steps: usize,
) -> Drag {
    let touch = Touch::new(scene);
    let Touch {
        model,
        full,
        inputs,
        none,
        f_ext,
    } = &touch;
    let mut reference = ContactReference::quasi_static(full).expect("reference");
    let mut est = Estimator::new(model).expect("estimator");
    let at = touch.along_normal(target);
    for k in 1..=1000 {
        let d = depth * (k as f64 / 200.0).min(1.0);
        est.step_with_tools(&[at(d)], inputs, none).expect("press");
    }
    let start = at(depth);
    let node = est.grasp(0).expect("a node near the tool");
    let (held, offset) = est.grasped(0).expect("grasping");
    assert_eq!(held, node);
    let place = |s: f64| [0, 1, 2].map(|c| start[c] + s * drag[c]);
    let want_at = |c: [f64; 3]| [0, 1, 2].map(|q| c[q] + offset[q]);
    let mut out = Drag {
        moving: 0.0,
        settled: 0.0,
        force: [0.0; 3],
    };
    for k in 1..=steps + 2000 {
        let c = place((k as f64 / steps as f64).min(1.0));
        est.step_with_tools(&[c], inputs, none).expect("drag");
        let tool = *est.tool_contact(0).expect("tool");
        assert_eq!(tool.status, ContactStatus::Grasping, "step {k}");
        assert_eq!(tool.active, 1, "one node held");
        if k % 25 == 0 && k <= steps {
            let want = reference
                .solve_static_grasp(node, want_at(c), f_ext)
                .expect("reference");
            out.moving = out.moving.max(relative(tool.force, want.force));
        }
    }
    let tool = *est.tool_contact(0).expect("tool");
    let want = reference
        .solve_static_grasp(node, want_at(place(1.0)), f_ext)
        .expect("reference");
    out.settled = relative(tool.force, want.force);
    out.force = tool.force;
    // Letting go gives no force at once: the tool is off the body after the drag.
    est.release(0);
    est.step_with_tools(&[place(1.0)], inputs, none)
        .expect("release");
    let tool = est.tool_contact(0).expect("tool");
    assert_eq!(tool.status, ContactStatus::Free, "released");
    assert_eq!(tool.force, [0.0; 3]);
    out
}

#[test]
fn a_grasped_point_dragged_gets_the_full_order_force_on_a_block() {
    let (dir, scene) = block_scene("grasp");
    // Pulled 0.6 mm up and 1 mm sideways from a 0.2 mm press.
    let out = grasp_and_drag(
        &scene,
        [0.008, 0.008, 0.008],
        2.0e-4,
        [1.0e-3, 0.0, 6.0e-4],
        2000,
    );
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "block grasp: dragged within {:.2e}, settled within {:.2e} of the full order's, force {:?} N",
        out.moving, out.settled, out.force
    );
    assert!(
        out.force[2] < 0.0,
        "pulled up, the body pulls the tool down"
    );
    assert!(
        out.moving < 0.02,
        "dragging force within 2 % ({})",
        out.moving
    );
    assert!(
        out.settled < 1e-4,
        "settled force within 1e-4 ({})",
        out.settled
    );
}

/// The held-out kidney: a point at its pole grasped and pulled outwards and sideways.
#[test]
fn a_grasped_point_dragged_gets_the_full_order_force_on_the_kidney() {
    let (dir, scene) = kidney_scene("grasp");
    let out = grasp_and_drag(
        &scene,
        [0.07, 0.025, 0.0],
        1.0e-3,
        [3.0e-3, 2.0e-3, 1.0e-3],
        2000,
    );
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "kidney grasp: dragged within {:.2e}, settled within {:.2e} of the full order's, force {:?} N",
        out.moving, out.settled, out.force
    );
    assert!(
        out.moving < 0.02,
        "dragging force within 2 % ({})",
        out.moving
    );
    assert!(
        out.settled < 1e-4,
        "settled force within 1e-4 ({})",
        out.settled
    );
}

/// Two tools at once on the block: one grasps a point and lifts it 0.4 mm, the other presses
/// 0.3 mm beside it; both settled forces against the full-order static solve of the two
/// together.
#[test]
fn a_grasper_and_a_probe_together_get_the_full_order_forces() {
    let (dir, scene) = block_scene("two");
    let touch = Touch::new(&scene);
    std::fs::remove_dir_all(&dir).ok();
    let Touch {
        model,
        full,
        inputs,
        none,
        f_ext,
    } = &touch;
    let radius = touch.radius();
    let mut est = Estimator::new(model).expect("estimator");
    let top = 0.008;
    // The grasper's centre `lift` above 0.2 mm deep, the probe's `d` deep (negative: clear).
    let grasper = |lift: f64| [0.005, 0.008, top + radius - 2.0e-4 + lift];
    let probe = |d: f64| [0.011, 0.008, top + radius - d];
    for k in 1..=1000 {
        let lift = 2.0e-4 * (1.0 - (k as f64 / 200.0).min(1.0));
        est.step_with_tools(&[grasper(lift), probe(-1e-3)], inputs, none)
            .expect("press");
    }
    let node = est.grasp(0).expect("grasp");
    let (_, offset) = est.grasped(0).expect("grasping");
    for k in 1..=4000 {
        let s = (k as f64 / 1000.0).min(1.0);
        est.step_with_tools(&[grasper(4.0e-4 * s), probe(3.0e-4 * s)], inputs, none)
            .expect("lift and press");
    }
    let held = *est.tool_contact(0).expect("grasper");
    let pressed = *est.tool_contact(1).expect("probe");
    assert_eq!(held.status, ContactStatus::Grasping);
    assert_eq!(pressed.status, ContactStatus::Touching);
    let mut reference = ContactReference::quasi_static(full).expect("reference");
    let target = [0, 1, 2].map(|c| grasper(4.0e-4)[c] + offset[c]);
    let (want_probe, want_held) = reference
        .solve_static_with_grasp(probe(3.0e-4), node, target, f_ext)
        .expect("reference");
    let (e_held, e_probe) = (
        relative(held.force, want_held),
        relative(pressed.force, want_probe.force),
    );
    eprintln!(
        "block, grasper and probe: grasper {:?} N within {e_held:.2e}, probe {:?} N ({} nodes) \
         within {e_probe:.2e} of the full order's",
        held.force, pressed.force, pressed.active
    );
    assert!(e_held < 1e-4, "grasper within 1e-4 ({e_held})");
    assert!(e_probe < 1e-4, "probe within 1e-4 ({e_probe})");
}

/// A grasp needs a node near the tool and a tool of the last step; a failed grasp changes
/// nothing, and a step without the tool lets go.
#[test]
fn a_grasp_is_refused_without_a_node_near_and_ends_without_its_tool() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let region = model.contact.as_ref().expect("contact region");
    let p = [0, 1, 2].map(|c| region.rest_positions.data[c]);
    let n = [0, 1, 2].map(|c| region.normals.data[c]);
    let radius = region.tool_radius;
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    assert!(matches!(est.grasp(0), Err(RuntimeError::NoSuchTool { .. })));
    let far = [0, 1, 2].map(|c| p[c] + n[c] * 3.0 * radius);
    est.step_with_tools(&[far], &inputs, &none).expect("step");
    let before = est.state().to_vec();
    assert!(matches!(
        est.grasp(0),
        Err(RuntimeError::NothingToGrasp { .. })
    ));
    assert!(matches!(est.grasp(1), Err(RuntimeError::NoSuchTool { .. })));
    assert_eq!(est.grasped(0), None);
    assert_eq!(est.state(), &before[..]);
    let touching = [0, 1, 2].map(|c| p[c] + n[c] * radius);
    est.step_with_tools(&[touching], &inputs, &none)
        .expect("step");
    est.grasp(0).expect("the node under the tool");
    est.step_with_tools(&[touching], &inputs, &none)
        .expect("step");
    assert_eq!(
        est.tool_contact(0).map(|t| t.status),
        Some(ContactStatus::Grasping)
    );
    est.step_with_tools(&[], &inputs, &none).expect("no tool");
    assert_eq!(est.grasped(0), None, "a step without the tool lets go");
    // A pull past the region's bound is clamped to it.
    est.step_with_tools(&[touching], &inputs, &none)
        .expect("step");
    est.grasp(0).expect("grasp again");
    let mut clamped = false;
    for k in 1..=400 {
        let c = [0, 1, 2].map(|q| touching[q] + n[q] * 1e-4 * k as f64);
        est.step_with_tools(&[c], &inputs, &none).expect("pull");
        let t = est.tool_contact(0).expect("tool");
        let mag = norm(t.force);
        assert!(
            mag.is_finite() && mag <= region.max_force * (1.0 + 1e-12),
            "step {k}: {mag}"
        );
        clamped |= t.status == ContactStatus::Clamped;
    }
    assert!(
        clamped,
        "pulled 40 mm off, the grasp reaches the force bound"
    );
}

/// The contact step allocates nothing: a press, a grasp, a slide and a lift with the force's σ
/// on.
#[test]
fn contact_steps_do_not_allocate() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let region = model.contact.as_ref().expect("contact region");
    let (_, p, n) = nearest_node(region, [0.020, 0.0, 0.00427]);
    let radius = region.tool_radius;
    let mut est = Estimator::new(&model).expect("estimator");
    est.set_contact_force_std(true);
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let path: Vec<[f64; 3]> = (0..600)
        .map(|k| {
            let d = 1e-3 * (k as f64 / 100.0).min(1.0) * if k < 500 { 1.0 } else { 0.0 };
            let slide = 2e-3 * (k as f64 / 600.0);
            [
                p[0] + n[0] * (radius - d),
                p[1] + n[1] * (radius - d) + slide,
                p[2] + n[2] * (radius - d),
            ]
        })
        .collect();
    // One warm-up step, then count.
    est.step_with_tools(&[path[0]], &inputs, &none)
        .expect("step");
    let (mut touched, mut held) = (0, 0);
    let allocations = counting_alloc::count(|| {
        for (k, c) in path.iter().enumerate().skip(1) {
            // Grasped at the deepest point of the press, dragged, let go before the lift.
            if k == 200 {
                est.grasp(0).expect("grasp");
            }
            if k == 400 {
                est.release(0);
            }
            est.step_with_tools(&[*c], &inputs, &none).expect("step");
            let t = est.tool_contact(0);
            touched += usize::from(t.is_some_and(|t| t.active > 0));
            held += usize::from(t.is_some_and(|t| t.status == ContactStatus::Grasping));
        }
    });
    assert!(touched > 300, "the path presses ({touched} steps touching)");
    assert_eq!(held, 200, "the grasp holds for 200 steps");
    assert_eq!(allocations, 0, "the contact step (and grasp) allocated");
}

/// The C ABI's contact step (runtime/examples/c/touch.c) gives the Rust estimator's forces bit
/// for bit, and refuses three tools.
#[test]
fn the_c_abi_presses_as_rust_does() {
    let compiled = compile(&scene(), &CompileOptions::default()).expect("compile");
    let model = compiled.model;
    let dir = std::env::temp_dir().join(format!("crokf-contact-capi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    let model_path = dir.join("touch.crokf");
    std::fs::write(&model_path, &compiled.bytes).expect("write model");
    let region = model.contact.as_ref().expect("contact region");
    let (_, p, n) = nearest_node(region, [0.020, 0.0, 0.00427]);
    let radius = region.tool_radius;
    let start = [0, 1, 2].map(|i| p[i] + n[i] * radius);
    let (depth, steps) = (8e-4, 60);
    let runtime = Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime");
    let exe = dir.join("touch");
    cdylib::compile_c(&runtime.join("examples/c/touch.c"), &exe);
    let mut args: Vec<String> = vec![model_path.display().to_string()];
    args.extend(start.iter().chain(&n).map(|v| format!("{v:.17e}")));
    args.push(format!("{depth:.17e}"));
    args.push(steps.to_string());
    let run = std::process::Command::new(&exe)
        .args(&args)
        .output()
        .expect("run touch");
    std::fs::remove_dir_all(&dir).ok();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "touch failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    // The same path in Rust, from the same parsed arguments.
    let parse = |s: &str| s.parse::<f64>().expect("number");
    let start: Vec<f64> = args[1..4].iter().map(|s| parse(s)).collect();
    let normal: Vec<f64> = args[4..7].iter().map(|s| parse(s)).collect();
    let depth = parse(&args[7]);
    let mut est = Estimator::new(&model).expect("estimator");
    let inputs = vec![0.0; model.inputs.len()];
    let none = vec![None; model.measurements.len()];
    let mut lines = stdout.lines();
    let mut touching = 0;
    for k in 1..=steps {
        let d = depth * k as f64 / steps as f64;
        let tool = [0, 1, 2].map(|i| start[i] - normal[i] * d);
        est.step_with_tools(&[tool], &inputs, &none).expect("step");
        let t = est.tool_contact(0).expect("tool");
        let line = lines.next().expect("a line per step");
        let f: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(f[0], k.to_string());
        for c in 0..3 {
            assert_eq!(
                parse(f[1 + c]).to_bits(),
                t.force[c].to_bits(),
                "step {k}: {line}"
            );
        }
        assert_eq!(f[4], t.active.to_string());
        touching += usize::from(t.active > 0);
    }
    assert!(touching > steps / 2, "the path presses ({touching} steps)");
    // Then the grasp of the node under the tool, pulled back out.
    let node = est.grasp(0).expect("grasp");
    assert_eq!(lines.next(), Some(format!("grasped {node}").as_str()));
    let mut pulling = 0;
    for k in 1..=steps {
        let d = depth * (steps - k) as f64 / steps as f64;
        let tool = [0, 1, 2].map(|i| start[i] - normal[i] * d);
        est.step_with_tools(&[tool], &inputs, &none).expect("step");
        let t = est.tool_contact(0).expect("tool");
        let line = lines.next().expect("a line per step");
        let f: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(f[0], (steps + k).to_string());
        for c in 0..3 {
            assert_eq!(
                parse(f[1 + c]).to_bits(),
                t.force[c].to_bits(),
                "step {}: {line}",
                steps + k
            );
        }
        assert_eq!(f[5], "5", "grasping");
        let along: f64 = (0..3).map(|c| t.force[c] * normal[c]).sum();
        pulling += usize::from(along < 0.0);
    }
    assert!(pulling > 0, "pulled out, the body holds the tool back");
    let refused = lines.next().expect("the refusal");
    assert!(refused.contains("at most 2"), "{refused}");
}
