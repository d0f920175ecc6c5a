//! docs/config.md is where users look up a key, so every key a config file may hold must be
//! there. The keys are read from the source of `src/config/`: every field of a struct or
//! struct-like variant that derives `Deserialize`, and every value of an enum whose variants
//! are spelled in the file (`kind = "…"`, `layout = "…"`).

mod common;

use std::collections::BTreeSet;

/// One key (or enum value) a config file may hold, and the item that declares it.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Key {
    item: String,
    name: String,
    /// An enum value is written quoted in a file; a field is a key or a table.
    is_value: bool,
}

/// How an enum's variant names are written in a file, from its `rename_all` (None: not
/// written at all, as for `untagged` enums whose variants are shapes, not words).
fn spelling(attributes: &str, variant: &str) -> Option<String> {
    if attributes.contains("untagged") {
        return None;
    }
    if attributes.contains("\"kebab-case\"") {
        let mut out = String::new();
        for (i, c) in variant.chars().enumerate() {
            if c.is_ascii_uppercase() && i > 0 {
                out.push('-');
            }
            out.push(c.to_ascii_lowercase());
        }
        return Some(out);
    }
    if attributes.contains("\"lowercase\"") {
        return Some(variant.to_lowercase());
    }
    Some(variant.to_string())
}

/// A field line inside an item body: `    pub name: Type,` or `        name: Type,`.
fn field_name(line: &str) -> Option<&str> {
    let t = line.trim_start();
    let t = t.strip_prefix("pub ").unwrap_or(t);
    let (name, rest) = t.split_once(':')?;
    let simple = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    (simple && rest.starts_with(' ') && !rest.starts_with(" :")).then_some(name)
}

/// A variant line of an enum body (four spaces, then a capitalised name).
fn variant_name(line: &str) -> Option<&str> {
    let t = line.strip_prefix("    ")?;
    if t.starts_with(' ') || !t.starts_with(|c: char| c.is_ascii_uppercase()) {
        return None;
    }
    let end = t
        .find(|c: char| !c.is_ascii_alphanumeric())
        .unwrap_or(t.len());
    Some(&t[..end])
}

/// A `#[derive(…)]` attribute's text, over as many lines as rustfmt spread it.
fn derive_list(lines: &[&str]) -> String {
    let mut text = String::new();
    for line in lines {
        text.push_str(line);
        if line.trim_end().ends_with(")]") {
            break;
        }
    }
    text
}

/// Every key and enum value declared by the `Deserialize` items of one source file.
fn keys_in(source: &str) -> Vec<Key> {
    let lines: Vec<&str> = source.lines().collect();
    let mut keys = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if !(lines[i].starts_with("#[derive(") && derive_list(&lines[i..]).contains("Deserialize"))
        {
            i += 1;
            continue;
        }
        let mut attributes = String::new();
        let mut j = i + 1;
        while j < lines.len() && !lines[j].starts_with("pub ") && !lines[j].starts_with("struct ") {
            attributes.push_str(lines[j]);
            j += 1;
        }
        let header = lines.get(j).copied().unwrap_or_default();
        if !header.trim_end().ends_with('{') {
            i = j + 1;
            continue;
        }
        let is_enum = header.contains(" enum ");
        let item = header.trim_end_matches('{').trim().to_string();
        let mut k = j + 1;
        let mut renamed: Option<String> = None;
        while k < lines.len() && lines[k] != "}" {
            let line = lines[k];
            if let Some(rest) = line.trim_start().strip_prefix("#[serde(rename = \"") {
                renamed = rest.split('"').next().map(str::to_string);
            }
            if !line.trim_start().starts_with("//") && !line.trim_start().starts_with("#[") {
                if let Some(name) = field_name(line) {
                    keys.push(Key {
                        item: item.clone(),
                        name: name.to_string(),
                        is_value: false,
                    });
                } else if let Some(v) = variant_name(line).filter(|_| is_enum) {
                    let spelled = renamed.take().or_else(|| spelling(&attributes, v));
                    if let Some(name) = spelled {
                        keys.push(Key {
                            item: item.clone(),
                            name,
                            is_value: true,
                        });
                    }
                }
            }
            k += 1;
        }
        i = k + 1;
    }
    keys
}

/// Whether docs/config.md mentions `key` the way a reader would look it up.
fn documented(docs: &str, key: &Key) -> bool {
    let n = &key.name;
    let forms = if key.is_value {
        vec![format!("`{n}`"), format!("\"{n}\"")]
    } else {
        vec![
            format!("`{n}`"),
            format!("[{n}]"),
            format!("[{n}."),
            format!("`{n} ="),
        ]
    };
    forms.iter().any(|f| docs.contains(f.as_str()))
}

fn config_sources() -> Vec<(String, String)> {
    let dir = common::repo_root().join("src/config");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "rs"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            (p.display().to_string(), text)
        })
        .collect()
}

#[test]
fn every_config_key_is_in_the_reference() {
    let docs = std::fs::read_to_string(common::repo_root().join("docs/config.md")).unwrap();
    let mut all = BTreeSet::new();
    let mut missing = Vec::new();
    for (file, text) in config_sources() {
        for key in keys_in(&text) {
            if !documented(&docs, &key) {
                missing.push(format!("{file}: {} `{}`", key.item, key.name));
            }
            all.insert(key);
        }
    }
    // The reader itself must find what every config has, or the check above checks nothing.
    for expected in [
        "connect_timeout_s",
        "frame_timeout_s",
        "max_views",
        "xarm",
        "mount",
    ] {
        assert!(
            all.iter().any(|k| k.name == expected),
            "the key reader missed `{expected}`"
        );
    }
    assert!(all.len() > 150, "only {} keys read", all.len());
    assert!(
        missing.is_empty(),
        "keys missing from docs/config.md:\n{}",
        missing.join("\n")
    );
}

/// The body lines of the item whose header line starts with `header`, up to its closing `}`
/// at column 0.
fn item_body<'a>(source: &'a str, header: &str) -> Option<Vec<&'a str>> {
    let mut lines = source.lines().skip_while(|l| !l.starts_with(header));
    lines.next()?;
    Some(lines.take_while(|l| *l != "}").collect())
}

/// The keys of each `kind` of a tagged table enum (`ArmConfig`, …): the fields of its
/// settings struct, or of its struct-like variant, by the kind's spelled name.
fn keys_by_kind(source: &str, enum_name: &str) -> Vec<(String, Vec<String>)> {
    let body = item_body(source, &format!("pub enum {enum_name} ")).unwrap();
    let mut kinds = Vec::new();
    for (i, line) in body.iter().enumerate() {
        let Some(variant) = variant_name(line) else {
            continue;
        };
        let kind = spelling("\"kebab-case\"", variant).unwrap();
        let rest = &line.trim()[variant.len()..];
        let fields: Vec<String> = if let Some(inner) = rest.strip_prefix('(') {
            let settings = inner.trim_end_matches([')', ',']);
            item_body(source, &format!("pub struct {settings} "))
                .unwrap_or_else(|| panic!("no struct {settings}"))
                .iter()
                .filter_map(|l| field_name(l).map(str::to_string))
                .collect()
        } else if rest.trim() == "{" {
            body[i + 1..]
                .iter()
                .take_while(|l| **l != "    },")
                .filter_map(|l| field_name(l).map(str::to_string))
                .collect()
        } else {
            Vec::new()
        };
        kinds.push((kind, fields));
    }
    kinds
}

/// The text of docs/config.md that documents `kind` of `[table]`: the table's preamble (keys
/// every kind takes) and the `### kind = "…"` section naming it.
fn kind_section(docs: &str, table: &str, kind: &str) -> Option<String> {
    let start = docs.find(&format!("## `[{table}]`"))?;
    let end = docs[start + 3..]
        .find("\n## ")
        .map_or(docs.len(), |e| start + 3 + e);
    let part = &docs[start..end];
    let preamble = &part[..part.find("\n### ").unwrap_or(part.len())];
    let heading = part.match_indices("\n### ").map(|(i, _)| i).find(|&i| {
        part[i..]
            .lines()
            .nth(1)
            .is_some_and(|h| h.contains(&format!("kind = \"{kind}\"")))
    })?;
    let section_end = part[heading + 5..]
        .find("\n### ")
        .map_or(part.len(), |e| heading + 5 + e);
    Some(format!("{preamble}{}", &part[heading..section_end]))
}

/// Names alone could be found in another kind's rows (`connect_timeout_s` is four kinds'),
/// so each kind's keys must be in that kind's own section.
#[test]
fn every_kind_documents_its_own_keys() {
    let docs = std::fs::read_to_string(common::repo_root().join("docs/config.md")).unwrap();
    let source: String = config_sources().into_iter().map(|(_, t)| t).collect();
    let mut checked = 0;
    let mut missing = Vec::new();
    for (table, enum_name) in [
        ("arm", "ArmConfig"),
        ("camera", "CameraConfig"),
        ("segmenter", "SegmenterConfig"),
    ] {
        for (kind, fields) in keys_by_kind(&source, enum_name) {
            let Some(section) = kind_section(&docs, table, &kind) else {
                missing.push(format!("[{table}] kind = \"{kind}\": no section"));
                continue;
            };
            for f in fields {
                checked += 1;
                if !section.contains(&format!("`{f}`")) {
                    missing.push(format!("[{table}] kind = \"{kind}\": `{f}`"));
                }
            }
        }
    }
    assert!(checked > 80, "only {checked} kind keys read");
    assert!(
        missing.is_empty(),
        "missing from their kind's section of docs/config.md:\n{}",
        missing.join("\n")
    );
}

#[test]
fn each_kind_is_checked_against_its_own_section_only() {
    let source = "pub enum ArmConfig {\n    Sim(SimSettings),\n    OtherKind {\n        own_key: u8,\n    },\n}\n\npub struct SimSettings {\n    pub start: f64,\n}\n";
    let kinds = keys_by_kind(source, "ArmConfig");
    assert_eq!(
        kinds,
        [
            ("sim".to_string(), vec!["start".to_string()]),
            ("other-kind".to_string(), vec!["own_key".to_string()]),
        ]
    );
    let docs = "## `[arm]`\n\nEvery kind takes `mount`.\n\n### `kind = \"sim\"`: a\n\n| `start` |\n\n### `kind = \"other-kind\"`: b\n\n| `start` |\n\n## `[camera]`\n\n| `own_key` |\n";
    let other = kind_section(docs, "arm", "other-kind").unwrap();
    assert!(other.contains("`mount`") && other.contains("`start`"));
    assert!(!other.contains("`own_key`"), "{other}");
    assert!(kind_section(docs, "arm", "sim")
        .unwrap()
        .contains("`start`"));
    assert!(kind_section(docs, "arm", "absent").is_none());
}

#[test]
fn the_key_reader_finds_fields_and_spelled_values() {
    let source = r#"
#[derive(
    Clone,
    Deserialize,
)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Thing {
    /// doc: not_a_key: here
    SimTruth {
        hidden_key: f64,
    },
    Plain(Other),
    #[serde(rename = "0-1")]
    Unit,
}

#[derive(Deserialize)]
#[serde(untagged)]
pub enum Shape {
    LookAt(A),
}

#[derive(Deserialize)]
pub struct Other {
    pub listed_key: Vec<u8>,
}
"#;
    let names: Vec<String> = keys_in(source).into_iter().map(|k| k.name).collect();
    assert_eq!(
        names,
        ["sim-truth", "hidden_key", "plain", "0-1", "listed_key"]
    );
    let docs = "| `hidden_key` | float | `\"0-1\"` |\n[[camera]]\nkind = \"plain\"";
    let found: Vec<bool> = keys_in(source)
        .iter()
        .map(|k| documented(docs, k))
        .collect();
    assert_eq!(found, [false, true, true, true, false]);
}
