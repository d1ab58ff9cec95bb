//! gmsh MSH 2.0–2.2, ASCII: the first element tag is the physical tag, the second the
//! elementary entity. gmsh writes an element once per physical group it belongs to (with a new
//! element number); such copies (same type, entity and nodes) are merged and keep the first
//! number.

use std::collections::HashMap;
use std::path::Path;

use super::{
    element_type_name, kept_dim, parse_num, parse_physical_names, Lines, MeshError, RawElement,
    RawMesh,
};

pub(super) fn read_msh2(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines = Lines::new(&text, 0, path);
    let mut raw = RawMesh::default();
    // (type, elementary entity, nodes) -> index into raw.elements, to merge per-group copies.
    let mut seen: HashMap<(u32, i64, Vec<u64>), usize> = HashMap::new();
    let (mut have_nodes, mut have_elements) = (false, false);
    while let Some((no, l)) = lines.next_opt() {
        match l {
            "" => {}
            "$MeshFormat" => lines.skip_to("$EndMeshFormat")?,
            "$PhysicalNames" => parse_physical_names(&mut lines, &mut raw.names)?,
            "$Nodes" => {
                if std::mem::replace(&mut have_nodes, true) {
                    return Err(lines.error(no, "second $Nodes section"));
                }
                let n = lines.count("nodes")?;
                raw.node_tags.reserve(n.min(1 << 24));
                raw.nodes.reserve(n.min(1 << 24));
                for _ in 0..n {
                    let (no, l) = lines.next("$Nodes")?;
                    let mut t = l.split_ascii_whitespace();
                    let tag: u64 = parse_num(&lines, no, t.next(), "node tag")?;
                    let mut x = [0.0; 3];
                    for (c, v) in x.iter_mut().enumerate() {
                        let what = format!("node {tag}: coordinate {}", ["x", "y", "z"][c]);
                        *v = parse_num(&lines, no, t.next(), &what)?;
                    }
                    raw.node_tags.push(tag);
                    raw.nodes.push(x);
                }
                lines.end("$EndNodes")?;
            }
            "$Elements" => {
                if std::mem::replace(&mut have_elements, true) {
                    return Err(lines.error(no, "second $Elements section"));
                }
                let n = lines.count("elements")?;
                for _ in 0..n {
                    let (no, l) = lines.next("$Elements")?;
                    let mut t = l.split_ascii_whitespace();
                    let tag: u64 = parse_num(&lines, no, t.next(), "element tag")?;
                    let what = format!("element {tag}");
                    let kind: u32 = parse_num(&lines, no, t.next(), &format!("{what}: type"))?;
                    let ntags: usize =
                        parse_num(&lines, no, t.next(), &format!("{what}: number of tags"))?;
                    let mut tags = Vec::with_capacity(ntags.min(16));
                    for _ in 0..ntags {
                        tags.push(parse_num::<i64>(
                            &lines,
                            no,
                            t.next(),
                            &format!("{what}: tag"),
                        )?);
                    }
                    let nodes = t
                        .map(|s| parse_num::<u64>(&lines, no, Some(s), &format!("{what}: node")))
                        .collect::<Result<Vec<u64>, _>>()?;
                    if let Some(dim) = kept_dim(kind) {
                        let expected = [1, 2, 3, 4][dim as usize];
                        if nodes.len() != expected {
                            return Err(lines.error(
                                no,
                                format!(
                                    "{what} of type {kind} ({}) has {} nodes, expected {expected}",
                                    element_type_name(kind),
                                    nodes.len()
                                ),
                            ));
                        }
                    }
                    let physical = match tags.first() {
                        Some(&p) if p != 0 => vec![i32::try_from(p).map_err(|_| {
                            lines.error(no, format!("{what}: physical tag {p} out of range"))
                        })?],
                        _ => Vec::new(),
                    };
                    let entity = tags.get(1).copied().unwrap_or(0);
                    match seen.entry((kind, entity, nodes)) {
                        std::collections::hash_map::Entry::Occupied(o) => {
                            let e = &mut raw.elements[*o.get()];
                            for p in physical {
                                if !e.physical.contains(&p) {
                                    e.physical.push(p);
                                }
                            }
                        }
                        std::collections::hash_map::Entry::Vacant(v) => {
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
                lines.end("$EndElements")?;
            }
            s if s.starts_with('$') && !s.starts_with("$End") => {
                let end = format!("$End{}", &s[1..]);
                lines.skip_to(&end)?;
            }
            _ => {
                return Err(lines.error(no, format!("unexpected {l:?} outside any section")));
            }
        }
    }
    Ok(raw)
}
