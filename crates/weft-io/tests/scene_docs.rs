//! `docs/scenes.md` documents every key the scene reader accepts, and nothing
//! else: for each section the set of keys in the first column of its table
//! equals the set serde's `deny_unknown_fields` lists for that section; keys
//! of inline tables (`grid = { ... }`, `motion = { ... }`) must be named in
//! their section's text.

use std::collections::BTreeSet;
use std::path::Path;

use weft_io::scene::parse_scene;

/// A scene using every section, so each can be probed with an unknown key.
const SCENE: &str = r#"
version = 1
[time]
end = 0.1
[contact]
thickness = 2e-3
[output]
frame_rate = 30
[camera]
eye = [1.0, 1.0, 1.0]
target = [0.0, 0.0, 0.0]
[[cloth]]
name = "c"
grid = { size = [0.2, 0.2], resolution = [4, 4], center = [0.0, 0.5, 0.0] }
[cloth.material]
density = 0.2
[[obstacle]]
name = "ball"
sphere = { center = [0.0, 0.0, 0.0], radius = 0.1 }
[obstacle.motion]
kind = "fixed"
[[pin]]
name = "p"
object = "c"
indices = [0]
[pin.motion]
kind = "fixed"
"#;

/// The keys serde accepts at `path` (e.g. `cloth.0.material`), read from the
/// message it gives for an unknown key there.
fn accepted(path: &str) -> BTreeSet<String> {
    let key = if path.is_empty() {
        "zz_unknown".to_string()
    } else {
        format!("{path}.zz_unknown")
    };
    let err = parse_scene(SCENE, Path::new("probe.toml"), &[format!("{key}=1")])
        .expect_err("an unknown key is refused")
        .to_string();
    let list = err
        .split_once("expected one of")
        .or_else(|| err.split_once("expected"))
        .unwrap_or_else(|| panic!("no key list for {path}: {err}"))
        .1;
    // The list may be followed by where the key was (`... in `time``).
    let list = list.split("in `").next().unwrap_or(list);
    list.split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect()
}

fn docs() -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/scenes.md");
    std::fs::read_to_string(p).expect("docs/scenes.md")
}

/// The text under the heading that contains `heading`, up to the next heading.
fn section<'a>(doc: &'a str, heading: &str) -> &'a str {
    let start = doc
        .find(heading)
        .unwrap_or_else(|| panic!("docs/scenes.md has no heading {heading}"));
    let rest = &doc[start..];
    let body = rest.find('\n').map_or(rest, |i| &rest[i..]);
    let end = body.find("\n#").map_or(body.len(), |i| i);
    &body[..end]
}

/// Whether `word` occurs in `text` delimited by non-identifier characters.
fn mentions(text: &str, word: &str) -> bool {
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    text.match_indices(word).any(|(i, _)| {
        let before = text[..i].chars().next_back().is_none_or(|c| !ident(c));
        let after = text[i + word.len()..]
            .chars()
            .next()
            .is_none_or(|c| !ident(c));
        before && after
    })
}

/// Backticked names in the first column of the section's table.
fn documented(text: &str) -> BTreeSet<String> {
    let mut keys = BTreeSet::new();
    for line in text.lines() {
        let Some(first) = line.strip_prefix('|').and_then(|l| l.split('|').next()) else {
            continue;
        };
        for (i, part) in first.split('`').enumerate() {
            if i % 2 == 1 && !part.is_empty() {
                keys.insert(part.to_string());
            }
        }
    }
    keys
}

#[test]
fn every_section_documents_exactly_its_keys() {
    let doc = docs();
    let sections = [
        ("", "## Top level"),
        ("time", "## `[time]`"),
        ("contact", "## `[contact]`"),
        ("output", "## `[output]`"),
        ("camera", "## `[camera]`"),
        ("cloth.0", "## `[[cloth]]`"),
        ("cloth.0.material", "### `[cloth.material]`"),
        ("obstacle.0", "## `[[obstacle]]`"),
        ("pin.0", "## `[[pin]]`"),
    ];
    for (path, heading) in sections {
        let code = accepted(path);
        let text = section(&doc, heading);
        let docs = documented(text);
        let undocumented: Vec<_> = code.difference(&docs).collect();
        let unknown: Vec<_> = docs.difference(&code).collect();
        assert!(
            undocumented.is_empty() && unknown.is_empty(),
            "{heading}: keys the reader accepts but the docs lack: {undocumented:?}; \
             keys the docs list but the reader refuses: {unknown:?}"
        );
    }
}

#[test]
fn inline_tables_name_every_key() {
    let doc = docs();
    let nested = [
        ("cloth.0.grid", "## `[[cloth]]`"),
        ("cloth.0.transform", "## `[[cloth]]`"),
        ("cloth.0.tube", "## `[[cloth]]`"),
        ("cloth.0.ribbon", "### The `ribbon` generator"),
        ("obstacle.0.box", "## `[[obstacle]]`"),
        ("obstacle.0.cylinder", "## `[[obstacle]]`"),
        ("obstacle.0.mesh_sequence", "## `[[obstacle]]`"),
        ("obstacle.0.sphere", "## `[[obstacle]]`"),
        ("obstacle.0.motion", "## `[[obstacle]]`"),
        ("pin.0.motion", "## `[[obstacle]]`"),
    ];
    for (path, heading) in nested {
        let text = section(&doc, heading);
        for key in accepted(path) {
            assert!(
                mentions(text, &key),
                "{path}.{key} is accepted but not documented under {heading}"
            );
        }
    }
}
