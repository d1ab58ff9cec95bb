//! gmsh MSH 2.0–2.2, ASCII: the first element tag is the physical tag, the second the
//! elementary entity. gmsh writes an element once per physical group it belongs to (with a new
//! element number); such copies (same type, entity and nodes) are merged and keep the first
//! number.

use std::path::Path;

use super::msh_text::{check_node_count, physical_tag, read_nodes, ElementMerger};
use super::{parse_num, parse_physical_names, Lines, MeshError, RawMesh};

pub(super) fn read_msh2(bytes: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut lines = Lines::new(&text, 0, path);
    let mut raw = RawMesh::default();
    let mut merger = ElementMerger::default();
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
                read_nodes(&mut lines, &mut raw, "$Nodes", "$EndNodes", "node tag")?;
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
                    check_node_count(&lines, no, &what, kind, nodes.len())?;
                    let physical =
                        physical_tag(&lines, no, &what, tags.first().copied().unwrap_or(0))?;
                    let entity = tags.get(1).copied().unwrap_or(0);
                    merger.add(&mut raw, tag, kind, entity, physical, nodes);
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
