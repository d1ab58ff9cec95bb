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

use std::path::Path;

use super::msh_text::{check_node_count, physical_tag, read_nodes, ElementMerger};
use super::{parse_num, Lines, MeshError, RawMesh};

/// Reads an MSH 1.0 file (bytes after any byte-order mark).
pub(super) fn read(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines = Lines::new(&text, 0, path);
    let mut raw = RawMesh::default();
    let mut merger = ElementMerger::default();
    let (mut have_nodes, mut have_elements) = (false, false);
    while let Some((no, l)) = lines.next_opt() {
        match l {
            "" => {}
            "$NOD" => {
                if std::mem::replace(&mut have_nodes, true) {
                    return Err(lines.error(no, "second $NOD section"));
                }
                read_nodes(&mut lines, &mut raw, "$NOD", "$ENDNOD", "node number")?;
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
                    check_node_count(&lines, no, &what, kind, count)?;
                    let physical = physical_tag(&lines, no, &what, phys)?;
                    merger.add(&mut raw, tag, kind, entity, physical, nodes);
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
