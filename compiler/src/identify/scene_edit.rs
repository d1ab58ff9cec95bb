//! The identified scene's text: the scene file with each excited load's `force_noise_std` and,
//! where the recording disagrees with the scene, `[reduction.corotational] model_error_scale`
//! set, every other byte kept (edits at the TOML parser's byte spans).

use crate::scene::{ForceModel, Scene, SceneFile};

use super::identification::{Identification, IdentifyError, BLOCKS};

/// The text of `scene` with each excited load's `force_noise_std` set to its identified σ_f
/// (rounded to 4 significant digits), `force_model = "random_walk"` made explicit, and a
/// comment line above the value naming this command, the recording and the uncertainty;
/// every other byte as in the file. The loads must be `[[load]]` tables. The result is
/// parsed back and compared with the scene (refused unless only those fields changed).
pub fn identified_scene(
    scene: &SceneFile,
    found: &Identification,
) -> Result<String, IdentifyError> {
    let values: Vec<(usize, f64, String)> = found
        .excited_loads()
        .map(|l| {
            let value: f64 = format!("{:.3e}", l.force.value)
                .parse()
                .unwrap_or(l.force.value);
            let comment = format!(
                "identified by crokf-compile identify from {} ({} steps, lags {}, skip {}): \
                 {:.3e} ± {:.1e} N per step (standard error over {BLOCKS} blocks); the scene's \
                 was {:.3e} ({})",
                found.recording,
                found.steps,
                found.lags,
                found.skip,
                l.force.value,
                l.force.uncertainty,
                l.scene_sigma,
                if l.stated {
                    "stated"
                } else {
                    "derived from range and rise_time"
                }
            );
            (l.load, value, comment)
        })
        .collect();
    let mut text = set_force_sigmas(&scene.text, &values)
        .map_err(|e| IdentifyError::Failed(format!("{}: {e}", scene.path.display())))?;
    let scale = found.model_error_changed().map(|m| {
        let value: f64 = format!("{:.3e}", m.value).parse().unwrap_or(m.value);
        let comment = format!(
            "identified by crokf-compile identify from {} ({} steps, lags {}, skip {}): {:.3} ± \
             {:.1e} (standard error over {BLOCKS} blocks); the scene's was {}",
            found.recording,
            found.steps,
            found.lags,
            found.skip,
            m.value,
            m.uncertainty,
            found.model_error.as_ref().map_or(1.0, |m| m.scene)
        );
        (value, comment)
    });
    if let Some((value, comment)) = &scale {
        text = set_model_error_scale(&text, *value, comment)
            .map_err(|e| IdentifyError::Failed(format!("{}: {e}", scene.path.display())))?;
    }
    // Only the stated fields changed: the parsed copy equals the scene with them set.
    let written = Scene::parse(&text, &scene.path)
        .map_err(|e| IdentifyError::Failed(format!("the edited scene does not parse: {e}")))?;
    let mut expected =
        Scene::parse(&scene.text, &scene.path).map_err(|e| IdentifyError::Failed(e.to_string()))?;
    for &(g, value, _) in &values {
        expected.loads[g].force_noise_std = value;
        expected.loads[g].force_model_stated = Some(ForceModel::RandomWalk);
    }
    if let (Some((value, _)), Some(spec)) = (&scale, expected.reduction.corotational.as_mut()) {
        spec.model_error_scale = Some(*value);
    }
    if written != expected {
        return Err(IdentifyError::Failed(format!(
            "{}: editing the scene changed more than its force σ and model-error factor; \
             write the loads as [[load]] tables and [reduction.corotational] as a table, with \
             one key per line",
            scene.path.display()
        )));
    }
    Ok(text)
}

/// A table's values as the TOML parser sees them (byte spans into the text).
type SpannedTable = std::collections::BTreeMap<String, toml::Spanned<toml::Value>>;

/// The `[[load]]` tables and `[reduction.corotational]` as the TOML parser sees them.
#[derive(serde::Deserialize)]
struct SpannedScene {
    #[serde(default)]
    load: Vec<SpannedTable>,
    reduction: Option<SpannedReduction>,
}

/// `[reduction]`'s `corotational` table.
#[derive(serde::Deserialize)]
struct SpannedReduction {
    corotational: Option<SpannedTable>,
}

/// The last table header before byte `at` of `body`, without spaces and comment
/// (`[[load]]`, `[reduction.corotational]`).
fn header_before(body: &str, at: usize) -> Option<String> {
    body[..at]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .map(|h| h.split('#').next().unwrap_or("").replace([' ', '\t'], ""))
}

/// A scene's text parsed with byte spans, for edits that keep every other byte (a byte-order
/// mark and CRLF line ends included).
struct SceneText<'a> {
    text: &'a str,
    /// Bytes of a leading byte-order mark (0 or 3).
    bom: usize,
    parsed: SpannedScene,
    newline: &'static str,
}

impl<'a> SceneText<'a> {
    fn parse(text: &'a str) -> Result<Self, String> {
        let bom = if text.starts_with('\u{feff}') { 3 } else { 0 };
        let parsed = toml::from_str(&text[bom..]).map_err(|e| e.to_string())?;
        let newline = if text.contains("\r\n") { "\r\n" } else { "\n" };
        Ok(SceneText {
            text,
            bom,
            parsed,
            newline,
        })
    }

    /// The text after the byte-order mark (the spans' reference).
    fn body(&self) -> &'a str {
        &self.text[self.bom..]
    }

    fn line_start(&self, at: usize) -> usize {
        self.body()[..at].rfind('\n').map_or(0, |i| i + 1)
    }

    fn line_end(&self, at: usize) -> usize {
        let body = self.body();
        body[at..].find('\n').map_or(body.len(), |i| at + i + 1)
    }

    /// The spaces and tabs that start the line at `line_start`.
    fn indent(&self, line_start: usize) -> String {
        self.body()[line_start..]
            .chars()
            .take_while(|c| *c == ' ' || *c == '\t')
            .collect()
    }

    /// The text with `edits` (byte ranges of the body, new text) applied from the end.
    fn edited(&self, mut edits: Vec<(std::ops::Range<usize>, String)>) -> String {
        edits.sort_by(|a, b| b.0.start.cmp(&a.0.start).then(b.0.end.cmp(&a.0.end)));
        let mut out = self.body().to_owned();
        for (range, new) in edits {
            out.replace_range(range, &new);
        }
        format!("{}{out}", &self.text[..self.bom])
    }
}

/// `text` with load `g`'s `force_noise_std` = value (and `force_model = "random_walk"`) for
/// each `(g, value, comment)`, the comment on a line of its own above the value.
fn set_force_sigmas(text: &str, values: &[(usize, f64, String)]) -> Result<String, String> {
    let scene = SceneText::parse(text)?;
    let (body, newline) = (scene.body(), scene.newline);
    let mut edits: Vec<(std::ops::Range<usize>, String)> = Vec::new();
    for (g, value, comment) in values {
        let table = scene
            .parsed
            .load
            .get(*g)
            .ok_or_else(|| format!("load {g} is not in the file"))?;
        let name = table
            .get("name")
            .ok_or_else(|| format!("load {g} has no name"))?;
        let start = scene.line_start(name.span().start);
        // The table must be a `[[load]]` table: its header is the last table header before
        // its name.
        if header_before(body, start).as_deref() != Some("[[load]]") {
            return Err(format!(
                "load '{}' is not a [[load]] table with one key per line: write it so to \
                 have its force σ written",
                name.get_ref().as_str().unwrap_or("?")
            ));
        }
        let indent = scene.indent(start);
        let comment_line = format!("{indent}# {comment}{newline}");
        let model_line = match table.get("force_model") {
            Some(_) => String::new(),
            None => format!("{indent}force_model = \"random_walk\"{newline}"),
        };
        let number = format!("{value:e}");
        match table.get("force_noise_std") {
            Some(old) => {
                let at = scene.line_start(old.span().start);
                edits.push((old.span(), number));
                edits.push((at..at, format!("{model_line}{comment_line}")));
            }
            None => {
                let last = table.values().map(|v| v.span().end).max().unwrap_or(0);
                let at = scene.line_end(last);
                let lead = if at == body.len() && !body.ends_with('\n') {
                    newline
                } else {
                    ""
                };
                edits.push((
                    at..at,
                    format!(
                        "{lead}{model_line}{comment_line}{indent}force_noise_std = {number}{newline}"
                    ),
                ));
            }
        }
    }
    Ok(scene.edited(edits))
}

/// `text` with `[reduction.corotational] model_error_scale = value`, the comment on a line of
/// its own above it: the key's line replaced where the table states it, else the key added
/// above the table's first key. The table must be written as a `[reduction.corotational]`
/// header with one key per line.
fn set_model_error_scale(text: &str, value: f64, comment: &str) -> Result<String, String> {
    let scene = SceneText::parse(text)?;
    let table = scene
        .parsed
        .reduction
        .as_ref()
        .and_then(|r| r.corotational.as_ref())
        .ok_or("no [reduction.corotational] table to write model_error_scale in")?;
    let first = table
        .values()
        .map(|v| scene.line_start(v.span().start))
        .min()
        .ok_or("[reduction.corotational] has no keys")?;
    if header_before(scene.body(), first).as_deref() != Some("[reduction.corotational]") {
        return Err(
            "[reduction.corotational] is not written as a table with one key per \
                    line: write it so to have model_error_scale written"
                .into(),
        );
    }
    let (range, indent) = match table.get("model_error_scale") {
        Some(old) => {
            let at = scene.line_start(old.span().start);
            (at..scene.line_end(old.span().end), scene.indent(at))
        }
        None => (first..first, String::new()),
    };
    let newline = scene.newline;
    let line =
        format!("{indent}# {comment}{newline}{indent}model_error_scale = {value:e}{newline}");
    Ok(scene.edited(vec![(range, line)]))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = "# a scene\n[mesh]\nfile = \"m.msh\"\n\n[[load]]\nname = \"tip\"\n\
        group = \"tip\"   # the end\nrange = 20.0\n\n[[load]]\n  name = \"side\"\n  \
        force_model = \"random_walk\"\n  force_noise_std = 0.5 # old\n  rise_time = 0.1\n\n\
        [time]\ndt = 0.001\n";

    /// A stated σ is replaced in place; a load without one gets `force_model` and the value
    /// after its last key; every other byte is kept.
    #[test]
    fn force_sigmas_are_set_and_the_rest_is_kept() {
        let out =
            set_force_sigmas(SCENE, &[(0, 0.25, "c0".into()), (1, 1.5e-3, "c1".into())]).unwrap();
        let expected = "# a scene\n[mesh]\nfile = \"m.msh\"\n\n[[load]]\nname = \"tip\"\n\
        group = \"tip\"   # the end\nrange = 20.0\nforce_model = \"random_walk\"\n# c0\n\
        force_noise_std = 2.5e-1\n\n[[load]]\n  name = \"side\"\n  \
        force_model = \"random_walk\"\n  # c1\n  force_noise_std = 1.5e-3 # old\n  rise_time = 0.1\n\n\
        [time]\ndt = 0.001\n";
        assert_eq!(out, expected);
        // CRLF line ends stay CRLF, a byte-order mark stays.
        let crlf = format!("\u{feff}{}", SCENE.replace('\n', "\r\n"));
        let out = set_force_sigmas(&crlf, &[(0, 0.25, "c0".into())]).unwrap();
        assert!(out.starts_with('\u{feff}'));
        assert!(out.contains(
            "range = 20.0\r\nforce_model = \"random_walk\"\r\n# c0\r\nforce_noise_std = 2.5e-1\r\n"
        ));
        assert_eq!(out.matches('\n').count(), out.matches("\r\n").count());
    }

    /// A load written as an inline table is refused, naming it.
    #[test]
    fn inline_loads_are_refused() {
        let text = "load = [{ name = \"tip\", range = 1.0 }]\n";
        let e = set_force_sigmas(text, &[(0, 0.25, "c".into())]).unwrap_err();
        assert!(e.contains("'tip'") && e.contains("[[load]]"), "{e}");
    }

    /// The tier's `model_error_scale`: replaced in place where `[reduction.corotational]`
    /// states it (its indent kept), else added as the table's first key; CRLF kept; a scene
    /// without that table header is refused.
    #[test]
    fn the_model_error_scale_is_set_in_its_table() {
        let text = "[reduction]\nmodel = \"corotational\"\n\n[reduction.corotational]\n\
            duration = 1.0\n  model_error_scale = 1.0 # was\n\n[time]\ndt = 0.001\n";
        let out = set_model_error_scale(text, 0.25, "c").unwrap();
        assert_eq!(
            out,
            "[reduction]\nmodel = \"corotational\"\n\n[reduction.corotational]\n\
            duration = 1.0\n  # c\n  model_error_scale = 2.5e-1\n\n[time]\ndt = 0.001\n"
        );
        let without = text.replace("  model_error_scale = 1.0 # was\n", "");
        let out = set_model_error_scale(&without, 0.25, "c").unwrap();
        assert!(
            out.contains("[reduction.corotational]\n# c\nmodel_error_scale = 2.5e-1\nduration"),
            "{out}"
        );
        // The key of another table is not taken for it.
        let other = without.replace("dt = 0.001", "dt = 0.001\nmodel_error_scale = 3.0");
        let out = set_model_error_scale(&other, 0.25, "c").unwrap();
        assert!(out.contains("model_error_scale = 3.0") && out.contains("= 2.5e-1\nduration"));
        let crlf = text.replace('\n', "\r\n");
        let out = set_model_error_scale(&crlf, 0.25, "c").unwrap();
        assert!(
            out.contains("  # c\r\n  model_error_scale = 2.5e-1\r\n"),
            "{out}"
        );
        assert_eq!(out.matches('\n').count(), out.matches("\r\n").count());
        let e = set_model_error_scale("[time]\ndt = 0.001\n", 0.25, "c").unwrap_err();
        assert!(e.contains("[reduction.corotational]"), "{e}");
    }
}
