//! Pieces shared by the line-oriented gmsh readers (MSH 1.0 and 2.2): the node section, the
//! node count of a kept element, and the merging of an element written once per physical
//! group it belongs to (same type, elementary entity and nodes: one element, first number kept,
//! physical tags united).

use std::collections::hash_map::Entry;
use std::collections::HashMap;

use super::{element_type_name, kept_dim, parse_num, Lines, MeshError, RawElement, RawMesh};

/// Reads `count node-lines` of a node section (`tag x y z` per line) up to `end`; `section`
/// and `tag_word` name the section and the tag in messages.
pub(super) fn read_nodes(
    lines: &mut Lines<'_>,
    raw: &mut RawMesh,
    section: &str,
    end: &str,
    tag_word: &str,
) -> Result<(), MeshError> {
    let n = lines.count("nodes")?;
    raw.node_tags.reserve(n.min(1 << 24));
    raw.nodes.reserve(n.min(1 << 24));
    for _ in 0..n {
        let (no, l) = lines.next(section)?;
        let mut t = l.split_ascii_whitespace();
        let tag: u64 = parse_num(lines, no, t.next(), tag_word)?;
        let mut x = [0.0; 3];
        for (c, v) in x.iter_mut().enumerate() {
            let what = format!("node {tag}: coordinate {}", ["x", "y", "z"][c]);
            *v = parse_num(lines, no, t.next(), &what)?;
        }
        raw.node_tags.push(tag);
        raw.nodes.push(x);
    }
    lines.end(end)
}

/// Refuses a kept element (point, line, triangle, tetrahedron) whose node count does not match
/// its type; `what` names the element, `no` the line.
pub(super) fn check_node_count(
    lines: &Lines<'_>,
    no: usize,
    what: &str,
    kind: u32,
    count: usize,
) -> Result<(), MeshError> {
    if let Some(dim) = kept_dim(kind) {
        let expected = [1, 2, 3, 4][dim as usize];
        if count != expected {
            return Err(lines.error(
                no,
                format!(
                    "{what} of type {kind} ({}) has {count} nodes, expected {expected}",
                    element_type_name(kind)
                ),
            ));
        }
    }
    Ok(())
}

/// The physical tag of an element line (0 or negative: none), range-checked.
pub(super) fn physical_tag(
    lines: &Lines<'_>,
    no: usize,
    what: &str,
    tag: i64,
) -> Result<Option<i32>, MeshError> {
    if tag <= 0 {
        return Ok(None);
    }
    i32::try_from(tag)
        .map(Some)
        .map_err(|_| lines.error(no, format!("{what}: physical tag {tag} out of range")))
}

/// Elements of one file, merged by (type, elementary entity, nodes).
#[derive(Default)]
pub(super) struct ElementMerger {
    seen: HashMap<(u32, i64, Vec<u64>), usize>,
}

impl ElementMerger {
    /// Adds an element line to `raw`, or unites its physical tag with an earlier copy's.
    pub(super) fn add(
        &mut self,
        raw: &mut RawMesh,
        tag: u64,
        kind: u32,
        entity: i64,
        physical: Option<i32>,
        nodes: Vec<u64>,
    ) {
        match self.seen.entry((kind, entity, nodes)) {
            Entry::Occupied(o) => {
                let e = &mut raw.elements[*o.get()];
                if let Some(p) = physical {
                    if !e.physical.contains(&p) {
                        e.physical.push(p);
                    }
                }
            }
            Entry::Vacant(v) => {
                raw.elements.push(RawElement {
                    tag,
                    kind,
                    physical: physical.into_iter().collect(),
                    nodes: v.key().2.clone(),
                });
                v.insert(raw.elements.len() - 1);
            }
        }
    }
}
