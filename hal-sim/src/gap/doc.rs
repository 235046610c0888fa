//! The model file as a TOML document the workflow edits: each effect found becomes a few
//! key edits (`[effects.*]` sections, or the `[piston]`/`[friction]` value it corrects), and
//! the edited document is what gets evaluated and written — so `DIR/model.toml` is exactly
//! the model the "after" figures were computed with.

use crate::plant::model::{model_section, Key, MachineModel, SectionKey};

/// One change to the model document, its keys typed ([`crate::plant::model::model_key!`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Edit {
    /// Sets a key to a number.
    Set(Key, f64),
    /// Sets a key to a boolean.
    SetBool(Key, bool),
    /// Removes a key.
    RemoveKey(Key),
    /// Removes a whole section.
    RemoveSection(SectionKey),
    /// Sets `[effects.extra_force]` to these terms (by basis name) and period, replacing
    /// what was there.
    SetExtraForce {
        /// Each term's name and coefficient, SI.
        terms: Vec<(&'static str, f64)>,
        /// Period of the periodic pair, m.
        period_m: Option<f64>,
    },
}

/// A model file as an editable TOML document: what the user wrote — comments, order,
/// formatting — is kept, and only the keys an edit touches change (`toml_edit`).
#[derive(Clone, Debug)]
pub struct ModelDoc {
    doc: toml_edit::DocumentMut,
}

impl PartialEq for ModelDoc {
    fn eq(&self, other: &Self) -> bool {
        self.doc.to_string() == other.doc.to_string()
    }
}

impl ModelDoc {
    /// Parses model text (already validated as a model by the caller).
    pub fn parse(text: &str) -> Result<Self, String> {
        text.parse::<toml_edit::DocumentMut>()
            .map(|doc| ModelDoc { doc })
            .map_err(|e| e.message().to_string())
    }

    /// The TOML text.
    pub fn to_text(&self) -> Result<String, String> {
        Ok(self.doc.to_string())
    }

    /// The validated model this document describes.
    pub fn model(&self) -> Result<MachineModel, String> {
        MachineModel::parse(&self.to_text()?).map_err(|e| e.0)
    }

    /// The number at `key`, if present.
    pub fn number(&self, key: Key) -> Option<f64> {
        let v = self.section(key.section)?.get(key.name)?.as_value()?;
        v.as_float().or_else(|| v.as_integer().map(|i| i as f64))
    }

    /// Whether the section exists.
    pub fn has_section(&self, section: SectionKey) -> bool {
        self.section(section.0).is_some()
    }

    fn section(&self, path: &str) -> Option<&dyn toml_edit::TableLike> {
        let mut t: &dyn toml_edit::TableLike = self.doc.as_table();
        for part in path.split('.') {
            t = t.get(part)?.as_table_like()?;
        }
        Some(t)
    }

    /// The section at `path`, created (its parents implicit: no `[effects]` header of their
    /// own) if missing.
    fn section_mut(&mut self, path: &str) -> Option<&mut toml_edit::Table> {
        let mut t = self.doc.as_table_mut();
        let mut parts = path.split('.').peekable();
        while let Some(part) = parts.next() {
            let last = parts.peek().is_none();
            let entry = t.entry(part).or_insert_with(|| {
                let mut new = toml_edit::Table::new();
                new.set_implicit(!last);
                toml_edit::Item::Table(new)
            });
            t = entry.as_table_mut()?;
        }
        Some(t)
    }

    /// Sets `name` in `table` to `value`, keeping the comment and spacing around an old value.
    fn set(table: &mut toml_edit::Table, name: &str, value: toml_edit::Value) {
        match table.get_mut(name).and_then(|i| i.as_value_mut()) {
            Some(old) => {
                let decor = old.decor().clone();
                *old = value;
                *old.decor_mut() = decor;
            }
            None => {
                table.insert(name, toml_edit::Item::Value(value));
            }
        }
    }

    /// This document with `comment` after the value at `key` on its line (`key = value  #
    /// comment`, replacing a comment there); unchanged where the key is absent.
    pub fn with_comment(&self, key: Key, comment: &str) -> Self {
        let mut d = self.clone();
        if d.number(key).is_some() {
            if let Some(v) = d
                .section_mut(key.section)
                .and_then(|t| t.get_mut(key.name))
                .and_then(|i| i.as_value_mut())
            {
                v.decor_mut().set_suffix(format!("  # {comment}"));
            }
        }
        d
    }

    /// This document with `edits` applied.
    pub fn with(&self, edits: &[Edit]) -> Self {
        let mut d = self.clone();
        for e in edits {
            match e {
                Edit::Set(k, v) => {
                    if let Some(t) = d.section_mut(k.section) {
                        Self::set(t, k.name, toml_edit::Value::from(*v));
                    }
                }
                Edit::SetBool(k, v) => {
                    if let Some(t) = d.section_mut(k.section) {
                        Self::set(t, k.name, toml_edit::Value::from(*v));
                    }
                }
                Edit::RemoveKey(k) => {
                    if d.section(k.section).is_some() {
                        if let Some(t) = d.section_mut(k.section) {
                            t.remove(k.name);
                        }
                    }
                }
                Edit::SetExtraForce { terms, period_m } => {
                    let path = model_section!(effects.extra_force).0;
                    if let Some(t) = d.section_mut(path) {
                        t.clear();
                        // Inline, as `docs/formats.md` writes it: `terms = { "x" = -1800.0 }`.
                        let mut table = toml_edit::InlineTable::new();
                        for (k, v) in terms {
                            table.insert(*k, toml_edit::Value::from(*v));
                        }
                        t.insert("terms", toml_edit::value(table));
                        if let Some(p) = period_m {
                            t.insert("period_m", toml_edit::value(*p));
                        }
                    }
                }
                Edit::RemoveSection(SectionKey(path)) => {
                    let (parent, name) = match path.rsplit_once('.') {
                        Some((p, n)) => (Some(p), n),
                        None => (None, *path),
                    };
                    let t = match parent {
                        Some(p) if d.section(p).is_some() => d.section_mut(p),
                        Some(_) => None,
                        None => Some(d.doc.as_table_mut()),
                    };
                    if let Some(t) = t {
                        t.remove(name);
                    }
                }
            }
        }
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::model::model_key;

    #[test]
    fn a_comment_beside_a_value_replaces_the_one_there_and_keeps_the_value() {
        let doc = ModelDoc::parse(crate::plant::model::REFERENCE_TOML).unwrap();
        let key = model_key!(piston / mass_kg);
        let before = doc.number(key).unwrap();
        let once = doc.with_comment(key, "10.0 ± 0.1 kg, first");
        let twice = once.with_comment(key, "10.00 ± 0.02 kg, second");
        let text = twice.to_text().unwrap();
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with("mass_kg"))
            .unwrap();
        assert!(line.ends_with("  # 10.00 ± 0.02 kg, second"), "{line}");
        assert!(!text.contains("first"));
        assert_eq!(twice.number(key), Some(before));
        twice.model().unwrap();
        // A key the document does not have is not created.
        let absent = model_key!(effects.slave_lag / delay_s);
        assert_eq!(doc.with_comment(absent, "x"), doc);
    }

    #[test]
    fn edits_add_replace_and_remove_effects_and_the_result_loads() {
        let doc = ModelDoc::parse(crate::plant::model::REFERENCE_TOML).unwrap();
        let d = doc.with(&[
            Edit::RemoveSection(model_section!(effects.cogging)),
            Edit::Set(model_key!(effects.slave_lag / delay_s), 7.5e-4),
            Edit::Set(model_key!(piston / mass_kg), 13.0),
        ]);
        let m = d.model().unwrap();
        assert!(m.effects.cogging.is_none());
        assert_eq!(
            m.effects.slave_lag.as_ref().map(|l| l.delay_s),
            Some(7.5e-4)
        );
        assert_eq!(m.piston.mass_kg, 13.0);
        assert_eq!(d.number(model_key!(piston / mass_kg)), Some(13.0));
        let cogging = model_section!(effects.cogging);
        assert!(!d.has_section(cogging) && doc.has_section(cogging));
        // A bad value is refused by the model's own validation, naming the key.
        let bad = doc.with(&[Edit::Set(model_key!(piston / mass_kg), -1.0)]);
        assert!(bad.model().unwrap_err().contains("piston.mass_kg"));
    }

    #[test]
    fn an_edited_model_differs_from_its_input_only_where_it_was_edited() {
        // The reference file: comments on every value, sections in the machine's order.
        let input = crate::plant::model::REFERENCE_TOML;
        let doc = ModelDoc::parse(input).unwrap();
        let out = doc
            .with(&[
                Edit::Set(model_key!(piston / mass_kg), 13.5),
                Edit::Set(model_key!(effects.slave_lag / delay_s), 7.5e-4),
                Edit::SetExtraForce {
                    terms: vec![("x", -1800.0), ("1", 162.0)],
                    period_m: None,
                },
            ])
            .to_text()
            .unwrap();
        let (old, new): (Vec<&str>, Vec<&str>) = (input.lines().collect(), out.lines().collect());
        // Every line of the input is still there, in order, but the mass's own line, which
        // keeps its comment.
        let changed: Vec<&&str> = old.iter().filter(|l| !new.contains(l)).collect();
        assert_eq!(changed.len(), 1, "{changed:?}");
        assert!(changed[0].starts_with("mass_kg = 12.0"), "{changed:?}");
        let mass = new.iter().find(|l| l.starts_with("mass_kg")).unwrap();
        assert!(mass.starts_with("mass_kg = 13.5") && mass.contains("# A (8–25 plausible)"));
        let mut rest = new.iter();
        for line in old.iter().filter(|l| !l.starts_with("mass_kg")) {
            assert!(
                rest.any(|l| l == line),
                "the input's line {line:?} is not kept in its place"
            );
        }
        // What was added: the new sections, at the end; the terms inline as docs/formats.md has them.
        let added: Vec<&&str> = new.iter().filter(|l| !old.contains(l)).collect();
        assert!(added.contains(&&"[effects.slave_lag]"), "{added:?}");
        assert!(
            added.iter().any(|l| l.starts_with("terms = {")),
            "{added:?}"
        );
        assert!(added.len() <= 7, "{added:?}");
        let m = ModelDoc::parse(&out).unwrap().model().unwrap();
        assert_eq!(m.piston.mass_kg, 13.5);
    }
}
