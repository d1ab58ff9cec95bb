//! gmsh MSH 4.1 (ASCII or binary) through `mshio` 0.4: physical tags come from `$Entities`,
//! names from `$PhysicalNames` (read here: mshio skips it; it is ASCII even in binary files).
//! mshio drops node tags when they are contiguous; they are then read back from the `$Nodes`
//! section here.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use super::{
    find_section, line_of, parse_physical_names, syntax, Header, Lines, MeshError, RawElement,
    RawMesh,
};

/// Reads `$PhysicalNames` wherever it is (it is ASCII in binary files too).
fn physical_names_41(
    bytes: &[u8],
    path: &Path,
    names: &mut BTreeMap<(u8, i32), String>,
) -> Result<(), MeshError> {
    let Some(start) = find_section(bytes, b"$PhysicalNames") else {
        return Ok(());
    };
    let end =
        find_section(&bytes[start..], b"$EndPhysicalNames").map_or(bytes.len(), |e| start + e);
    let text = String::from_utf8_lossy(&bytes[start..end]);
    let mut lines = Lines::new(&text, line_of(bytes, start) - 1, path);
    parse_physical_names(&mut lines, names)
}

/// Bounds-checked reader of binary MSH 4.1 values.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    big_endian: bool,
    size_t: usize,
}

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let s = self.bytes.get(self.pos..self.pos.checked_add(N)?)?;
        self.pos += N;
        let mut a: [u8; N] = s.try_into().ok()?;
        if self.big_endian {
            a.reverse();
        }
        Some(a)
    }

    fn size_t(&mut self) -> Option<u64> {
        if self.size_t == 4 {
            self.take::<4>().map(|a| u32::from_le_bytes(a) as u64)
        } else {
            self.take::<8>().map(u64::from_le_bytes)
        }
    }

    fn int(&mut self) -> Option<i32> {
        self.take::<4>().map(i32::from_le_bytes)
    }

    fn skip(&mut self, n: u64) -> Option<()> {
        let n = usize::try_from(n).ok()?;
        let end = self.pos.checked_add(n)?;
        (end <= self.bytes.len()).then(|| self.pos = end)
    }
}

/// Node tags of every `$Nodes` block, read directly from the section (mshio drops them when
/// they are contiguous). One Vec per block.
fn node_tags_41(bytes: &[u8], header: &Header, path: &Path) -> Result<Vec<Vec<u64>>, MeshError> {
    let start = find_section(bytes, b"$Nodes")
        .ok_or_else(|| syntax(path, "$Nodes".into(), "cannot locate the $Nodes section"))?;
    let truncated = |off: usize| {
        let location = if header.binary {
            format!("byte {off}")
        } else {
            format!("line {}", line_of(bytes, off))
        };
        syntax(path, location, "$Nodes section malformed or truncated")
    };
    let blocks = if header.binary {
        let mut c = Cursor {
            bytes,
            pos: start,
            big_endian: header.big_endian,
            size_t: header.data_size,
        };
        let mut read = || -> Option<Vec<Vec<u64>>> {
            let num_blocks = c.size_t()?;
            for _ in 0..3 {
                c.size_t()?;
            }
            let mut blocks = Vec::new();
            for _ in 0..num_blocks {
                c.int()?;
                c.int()?;
                let parametric = c.int()?;
                let n = c.size_t()?;
                if parametric != 0 {
                    return None;
                }
                let mut tags = Vec::with_capacity(usize::try_from(n).ok()?.min(1 << 20));
                for _ in 0..n {
                    tags.push(c.size_t()?);
                }
                c.skip(n.checked_mul(24)?)?;
                blocks.push(tags);
            }
            Some(blocks)
        };
        read().ok_or_else(|| truncated(c.pos))?
    } else {
        let text = String::from_utf8_lossy(&bytes[start..]);
        ascii_node_tags(&text).ok_or_else(|| truncated(start))?
    };
    Ok(blocks)
}

/// Node tags per block of an ASCII `$Nodes` section body.
fn ascii_node_tags(text: &str) -> Option<Vec<Vec<u64>>> {
    fn num(tok: &mut std::str::SplitAsciiWhitespace<'_>) -> Option<u64> {
        tok.next().and_then(|t| t.parse::<u64>().ok())
    }
    let mut tok = text.split_ascii_whitespace();
    let num_blocks = num(&mut tok)?;
    for _ in 0..3 {
        num(&mut tok)?;
    }
    let mut blocks = Vec::new();
    for _ in 0..num_blocks {
        num(&mut tok)?; // entity dim
        tok.next()?; // entity tag (int)
        let parametric = num(&mut tok)?;
        let n = num(&mut tok)?;
        if parametric != 0 {
            return None;
        }
        let mut tags = Vec::with_capacity(usize::try_from(n).ok()?.min(1 << 20));
        for _ in 0..n {
            tags.push(num(&mut tok)?);
        }
        for _ in 0..n.checked_mul(3)? {
            tok.next()?; // coordinates: only their presence matters here
        }
        blocks.push(tags);
    }
    Some(blocks)
}

/// Location and message of an mshio parse error (innermost error first in its backtrace).
fn describe_mshio_error(
    bytes: &[u8],
    binary: bool,
    e: &mshio::MshParserError<&[u8]>,
) -> (String, String) {
    let base = bytes.as_ptr() as usize;
    let offset = e
        .begin_msh_errors()
        .next()
        .or(e.backtrace.first())
        .map(|(s, _)| (s.as_ptr() as usize).saturating_sub(base).min(bytes.len()))
        .unwrap_or(0);
    let location = if binary {
        format!("byte {offset}")
    } else {
        format!("line {}", line_of(bytes, offset))
    };
    let mut parts: Vec<String> = e
        .filter_msh_errors()
        .map(|(_, k)| k.to_string().trim_end_matches('.').to_owned())
        .collect();
    parts.reverse();
    parts.dedup();
    let message = if parts.is_empty() {
        "malformed MSH 4.1 content (file truncated?)".to_owned()
    } else {
        format!(
            "malformed MSH 4.1 content (file truncated?): {}",
            parts.join(": ")
        )
    };
    (location, message)
}

/// Whether the `$Nodes` or `$Elements` section (`marker`) exists and declares 0 entries.
fn section_is_empty(bytes: &[u8], header: &Header, marker: &[u8]) -> bool {
    let Some(start) = find_section(bytes, marker) else {
        return false;
    };
    if header.binary {
        let mut c = Cursor {
            bytes,
            pos: start,
            big_endian: header.big_endian,
            size_t: header.data_size,
        };
        c.size_t().and_then(|_| c.size_t()) == Some(0)
    } else {
        let head = &bytes[start..bytes.len().min(start + 200)];
        let head = String::from_utf8_lossy(head);
        head.split_ascii_whitespace().nth(1) == Some("0")
    }
}

pub(super) fn read_msh41(bytes: &[u8], header: &Header, path: &Path) -> Result<RawMesh, MeshError> {
    // mshio 0.4 computes `count - 1` on u64 for these sections: an empty one overflows.
    if section_is_empty(bytes, header, b"$Nodes") || section_is_empty(bytes, header, b"$Elements") {
        return Err(MeshError::NoTetrahedra {
            path: path.to_owned(),
        });
    }
    // mshio 0.4 panics on a few malformed inputs (`unimplemented!`, `expect`, overflow);
    // those known are checked above; any other panic is caught quietly and reported as a
    // parse error.
    let parsed = super::guard::quietly(|| {
        mshio::parse_msh_bytes(bytes).map_err(|e| describe_mshio_error(bytes, header.binary, &e))
    });
    let gave_up = "malformed MSH 4.1 content: the mshio parser gave up on it (a count, tag or \
         size that does not match the data that follows)";
    let msh = match parsed {
        Ok(Ok(msh)) => msh,
        Ok(Err((location, message))) => return Err(syntax(path, location, message)),
        Err(()) => return Err(syntax(path, "MSH 4.1 body".into(), gave_up)),
    };

    let mut raw = RawMesh::default();
    physical_names_41(bytes, path, &mut raw.names)?;

    // Physical tags of each entity (dim, tag).
    let mut physical: HashMap<(i32, i32), Vec<i32>> = HashMap::new();
    if let Some(ent) = &msh.data.entities {
        for p in &ent.points {
            physical.insert((0, p.tag), p.physical_tags.clone());
        }
        for c in &ent.curves {
            physical.insert((1, c.tag), c.physical_tags.clone());
        }
        for s in &ent.surfaces {
            physical.insert((2, s.tag), s.physical_tags.clone());
        }
        for v in &ent.volumes {
            physical.insert((3, v.tag), v.physical_tags.clone());
        }
    }

    if let Some(nodes) = &msh.data.nodes {
        let scanned = if nodes.node_blocks.iter().any(|b| b.node_tags.is_none()) {
            Some(node_tags_41(bytes, header, path)?)
        } else {
            None
        };
        for (k, block) in nodes.node_blocks.iter().enumerate() {
            let tags: Vec<u64> = match (&block.node_tags, &scanned) {
                (Some(map), _) => {
                    let mut tags = vec![0; block.nodes.len()];
                    for (&tag, &i) in map {
                        if let Some(t) = tags.get_mut(i) {
                            *t = tag;
                        }
                    }
                    tags
                }
                (None, Some(s)) => s.get(k).cloned().unwrap_or_default(),
                (None, None) => Vec::new(),
            };
            if tags.len() != block.nodes.len() || tags.contains(&0) {
                return Err(syntax(
                    path,
                    "$Nodes".into(),
                    format!(
                        "node block {} (entity {}:{}): cannot recover its {} node tags",
                        k + 1,
                        block.entity_dim,
                        block.entity_tag,
                        block.nodes.len()
                    ),
                ));
            }
            raw.node_tags.extend_from_slice(&tags);
            raw.nodes
                .extend(block.nodes.iter().map(|n| [n.x, n.y, n.z]));
        }
    }

    if let Some(elements) = &msh.data.elements {
        for block in &elements.element_blocks {
            let kind = block.element_type as u32;
            let phys = physical
                .get(&(block.entity_dim, block.entity_tag))
                .cloned()
                .unwrap_or_default();
            for e in &block.elements {
                raw.elements.push(RawElement {
                    tag: e.element_tag,
                    kind,
                    physical: phys.clone(),
                    nodes: e.nodes.clone(),
                });
            }
        }
    }
    Ok(raw)
}
