//! Arbaro species files: `<arbaro><species name="…"><param name="Shape" value="7"/>…`.
//! Parameters a file omits keep Arbaro's defaults; every unknown name and bad value is
//! reported, by name and line, in one error.

use crate::weber_penn::params::IGNORED_NAMES;
use crate::weber_penn::Params;
use std::path::Path;

/// A species read from an Arbaro file.
#[derive(Debug, Clone, PartialEq)]
pub struct ArbaroSpecies {
    /// The `name` attribute of `<species>` (or the `Species` parameter).
    pub name: String,
    pub params: Params,
    /// `RandomSeed`, when the file gives one.
    pub seed: Option<u64>,
}

#[derive(Debug, thiserror::Error)]
pub enum ArbaroError {
    /// A species file that cannot be read (missing, not a regular file, too large, not text).
    #[error(transparent)]
    Input(#[from] sylva_core::InputError),
    #[error("{origin}: malformed XML: {message}")]
    Xml { origin: String, message: String },
    #[error("{origin}: {message}")]
    Structure { origin: String, message: String },
    #[error("{origin}: {}", problems.join("; "))]
    Params {
        origin: String,
        /// One entry per bad parameter: `line N: parameter 'X' ...`.
        problems: Vec<String>,
    },
}

/// Reads an Arbaro species file.
pub fn load_file(path: &Path) -> Result<ArbaroSpecies, ArbaroError> {
    let origin = path.display().to_string();
    let text = sylva_core::read_text_file(
        path,
        sylva_core::limits::TEXT_FILE_BYTES,
        "Arbaro species files",
    )?;
    parse(&text, &origin)
}

/// Parses Arbaro XML; `origin` names the source in errors.
pub fn parse(text: &str, origin: &str) -> Result<ArbaroSpecies, ArbaroError> {
    let structure = |message: String| ArbaroError::Structure {
        origin: origin.to_string(),
        message,
    };
    let doc = roxmltree::Document::parse(text).map_err(|e| ArbaroError::Xml {
        origin: origin.to_string(),
        message: e.to_string(),
    })?;
    let line_of = |n: roxmltree::Node| doc.text_pos_at(n.range().start).row;
    let root = doc.root_element();
    if root.tag_name().name() != "arbaro" {
        return Err(structure(format!(
            "root element is <{}>, expected <arbaro>",
            root.tag_name().name()
        )));
    }
    let species: Vec<_> = root
        .children()
        .filter(|n| n.is_element() && n.tag_name().name() == "species")
        .collect();
    let node = match species.as_slice() {
        [one] => *one,
        [] => return Err(structure("no <species> element inside <arbaro>".into())),
        _ => {
            return Err(structure(format!(
                "{} <species> elements; a file holds one species",
                species.len()
            )))
        }
    };
    let mut name = node.attribute("name").unwrap_or("").to_string();
    let mut params = Params::default();
    let mut seed = None;
    let mut problems = Vec::new();
    for p in node.children().filter(|n| n.is_element()) {
        let line = line_of(p);
        if p.tag_name().name() != "param" {
            problems.push(format!(
                "line {line}: unexpected element <{}> (expected <param>)",
                p.tag_name().name()
            ));
            continue;
        }
        let (Some(pname), Some(value)) = (p.attribute("name"), p.attribute("value")) else {
            problems.push(format!(
                "line {line}: <param> needs both a name and a value attribute"
            ));
            continue;
        };
        if pname == "Species" {
            if name.is_empty() {
                name = value.to_string();
            }
            continue;
        }
        let number: f64 = match value.trim().parse() {
            Ok(v) => v,
            Err(_) => {
                problems.push(format!(
                    "line {line}: parameter '{pname}' = '{value}' is not a number"
                ));
                continue;
            }
        };
        if pname == "RandomSeed" {
            if number.is_finite() && number >= 0.0 && number.fract() == 0.0 {
                seed = Some(number as u64);
            } else {
                problems.push(format!(
                    "line {line}: parameter 'RandomSeed' = {value} must be a whole number ≥ 0"
                ));
            }
            continue;
        }
        debug_assert!(!IGNORED_NAMES.contains(&pname));
        if let Err(e) = params.set(pname, number) {
            problems.push(format!("line {line}: {e}"));
        }
    }
    if !problems.is_empty() {
        return Err(ArbaroError::Params {
            origin: origin.to_string(),
            problems,
        });
    }
    if name.is_empty() {
        name = "arbaro_species".into();
    }
    Ok(ArbaroSpecies { name, params, seed })
}

/// Writes `params` as an Arbaro species file (every parameter, so defaults are explicit).
pub fn to_xml(name: &str, params: &Params) -> String {
    let esc = |s: &str| {
        s.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('"', "&quot;")
    };
    let mut out = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<arbaro>\n");
    out.push_str(&format!("  <species name=\"{}\">\n", esc(name)));
    for (n, v) in params.entries() {
        out.push_str(&format!("    <param name=\"{n}\" value=\"{v}\"/>\n"));
    }
    out.push_str("  </species>\n</arbaro>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn omitted_parameters_take_defaults_either_quote_style() {
        let xml = r#"<?xml version="1.0"?>
<arbaro>
  <species name="quaking_aspen">
    <param name="Shape" value="7"/>
    <param name='BaseSize' value='0.4'/>
    <param name="1Branches" value='50'/>
    <param name="Species" value="ignored because the attribute wins"/>
    <param name="RandomSeed" value="13"/>
  </species>
</arbaro>"#;
        let s = parse(xml, "aspen.xml").unwrap();
        assert_eq!(s.name, "quaking_aspen");
        assert_eq!(s.seed, Some(13));
        assert_eq!(s.params.general.shape, 7.0);
        assert_eq!(s.params.general.base_size, 0.4);
        assert_eq!(s.params.levels[1].branches, 50.0);
        // Omitted: Arbaro defaults.
        let d = Params::default();
        assert_eq!(s.params.general.ratio, d.general.ratio);
        assert_eq!(s.params.levels[2].down_angle, d.levels[2].down_angle);
        assert_eq!(s.params.general.scale, 10.0);
    }

    #[test]
    fn every_bad_parameter_is_reported_by_name_and_line() {
        let xml = "<arbaro><species name=\"x\">\n\
                   <param name=\"Shape\" value=\"12\"/>\n\
                   <param name=\"Frobnicate\" value=\"1\"/>\n\
                   <param name=\"1Length\" value=\"abc\"/>\n\
                   <param name=\"Levels\" value=\"NaN\"/>\n\
                   <param name=\"Ratio\" value=\"0.02\"/>\n\
                   </species></arbaro>";
        let e = parse(xml, "bad.xml").unwrap_err();
        let msg = e.to_string();
        assert!(msg.starts_with("bad.xml: "), "{msg}");
        assert!(
            msg.contains("line 2: parameter 'Shape' = 12 is outside [0, 8]"),
            "{msg}"
        );
        assert!(
            msg.contains("line 3: unknown parameter 'Frobnicate'"),
            "{msg}"
        );
        assert!(
            msg.contains("line 4: parameter '1Length' = 'abc' is not a number"),
            "{msg}"
        );
        assert!(
            msg.contains("'Levels'") && msg.contains("not a finite number"),
            "{msg}"
        );
        assert!(!msg.contains("Ratio"), "{msg}");
        match e {
            ArbaroError::Params { problems, .. } => assert_eq!(problems.len(), 4),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn malformed_and_misshapen_files() {
        let e = parse("<arbaro><species>", "a.xml").unwrap_err();
        assert!(matches!(e, ArbaroError::Xml { .. }), "{e}");
        let e = parse("<tree/>", "b.xml").unwrap_err();
        assert!(e.to_string().contains("expected <arbaro>"), "{e}");
        let e = parse("<arbaro></arbaro>", "c.xml").unwrap_err();
        assert!(e.to_string().contains("no <species>"), "{e}");
        let e = parse(
            "<arbaro><species><param name=\"Shape\"/></species></arbaro>",
            "d.xml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("name and a value"), "{e}");
        let e = load_file(Path::new("/nonexistent/x.xml")).unwrap_err();
        assert!(
            e.to_string().starts_with("/nonexistent/x.xml: cannot read"),
            "{e}"
        );
    }

    #[test]
    fn round_trip_through_xml() {
        let sp = crate::species::Species::builtin("paper_birch").unwrap();
        let xml = to_xml(&sp.name, &sp.params);
        let back = parse(&xml, "rt.xml").unwrap();
        assert_eq!(back.name, "paper_birch");
        assert_eq!(back.params, sp.params);
    }
}
