//! gmsh MSH 1.0 (ASCII), the format of gmsh before 2.0 and of many older data sets:
//!
//! ```text
//! $NOD
//! number-of-nodes
//! node-number x y z
//! $ENDNOD
//! $ELM
//! number-of-elements
//! elm-number elm-type reg-phys reg-elem number-of-nodes node-number-list
//! $ENDELM
//! ```
//!
//! Element types are gmsh's (4 = tet4, 2 = tri3, 1 = line2, 15 = point). `reg-phys` is the
//! physical tag (0: none); MSH 1.0 has no physical names, so the groups are named `"<dim>:<tag>"`.
//! As in MSH 2.2, gmsh writes an element once per physical group it belongs to; copies (same
//! type, elementary region and nodes) are merged and keep the first number.

use std::collections::hash_map::Entry;
use std::collections::HashMap;
use std::path::Path;

use super::{element_type_name, kept_dim, parse_num, Lines, MeshError, RawElement, RawMesh};

/// Reads an MSH 1.0 file (bytes after any byte-order mark).
pub(super) fn read(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines = Lines::new(&text, 0, path);
    let mut raw = RawMesh::default();
    let mut seen: HashMap<(u32, i64, Vec<u64>), usize> = HashMap::new();
    let (mut have_nodes, mut have_elements) = (false, false);
    while let Some((no, l)) = lines.next_opt() {
        match l {
            "" => {}
            "$NOD" => {
                if std::mem::replace(&mut have_nodes, true) {
                    return Err(lines.error(no, "second $NOD section"));
                }
                let n = lines.count("nodes")?;
                raw.node_tags.reserve(n.min(1 << 24));
                raw.nodes.reserve(n.min(1 << 24));
                for _ in 0..n {
                    let (no, l) = lines.next("$NOD")?;
                    let mut t = l.split_ascii_whitespace();
                    let tag: u64 = parse_num(&lines, no, t.next(), "node number")?;
                    let mut x = [0.0; 3];
                    for (c, v) in x.iter_mut().enumerate() {
                        let what = format!("node {tag}: coordinate {}", ["x", "y", "z"][c]);
                        *v = parse_num(&lines, no, t.next(), &what)?;
                    }
                    raw.node_tags.push(tag);
                    raw.nodes.push(x);
                }
                lines.end("$ENDNOD")?;
            }
            "$ELM" => {
                if std::mem::replace(&mut have_elements, true) {
                    return Err(lines.error(no, "second $ELM section"));
                }
                let n = lines.count("elements")?;
                for _ in 0..n {
                    let (no, l) = lines.next("$ELM")?;
                    let mut t = l.split_ascii_whitespace();
                    let tag: u64 = parse_num(&lines, no, t.next(), "element number")?;
                    let what = format!("element {tag}");
                    let kind: u32 = parse_num(&lines, no, t.next(), &format!("{what}: type"))?;
                    let phys: i64 = parse_num(&lines, no, t.next(), &format!("{what}: reg-phys"))?;
                    let entity: i64 =
                        parse_num(&lines, no, t.next(), &format!("{what}: reg-elem"))?;
                    let count: usize =
                        parse_num(&lines, no, t.next(), &format!("{what}: number of nodes"))?;
                    let nodes = t
                        .map(|s| parse_num::<u64>(&lines, no, Some(s), &format!("{what}: node")))
                        .collect::<Result<Vec<u64>, _>>()?;
                    if nodes.len() != count {
                        return Err(lines.error(
                            no,
                            format!("{what} declares {count} nodes but lists {}", nodes.len()),
                        ));
                    }
                    if let Some(dim) = kept_dim(kind) {
                        let expected = [1, 2, 3, 4][dim as usize];
                        if count != expected {
                            return Err(lines.error(
                                no,
                                format!(
                                    "{what} of type {kind} ({}) has {count} nodes, expected \
                                     {expected}",
                                    element_type_name(kind)
                                ),
                            ));
                        }
                    }
                    let physical = if phys > 0 {
                        vec![i32::try_from(phys).map_err(|_| {
                            lines.error(no, format!("{what}: physical tag {phys} out of range"))
                        })?]
                    } else {
                        Vec::new()
                    };
                    match seen.entry((kind, entity, nodes)) {
                        Entry::Occupied(o) => {
                            let e = &mut raw.elements[*o.get()];
                            for p in physical {
                                if !e.physical.contains(&p) {
                                    e.physical.push(p);
                                }
                            }
                        }
                        Entry::Vacant(v) => {
                            raw.elements.push(RawElement {
                                tag,
                                kind,
                                physical,
                                nodes: v.key().2.clone(),
                            });
                            v.insert(raw.elements.len() - 1);
                        }
                    }
                }
                lines.end("$ENDELM")?;
            }
            _ => {
                return Err(lines.error(
                    no,
                    format!("unexpected {l:?} in an MSH 1.0 file (expected $NOD or $ELM)"),
                ));
            }
        }
    }
    if !have_nodes {
        return Err(lines.error(lines.last, "MSH 1.0 file without a $NOD section"));
    }
    Ok(raw)
}
