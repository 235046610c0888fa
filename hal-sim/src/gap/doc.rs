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

/// A model file as an editable TOML table.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelDoc {
    table: toml::Table,
}

impl ModelDoc {
    /// Parses model text (already validated as a model by the caller).
    pub fn parse(text: &str) -> Result<Self, String> {
        text.parse::<toml::Table>()
            .map(|table| ModelDoc { table })
            .map_err(|e| e.message().to_string())
    }

    /// The TOML text.
    pub fn to_text(&self) -> Result<String, String> {
        toml::to_string(&self.table).map_err(|e| e.to_string())
    }

    /// The validated model this document describes.
    pub fn model(&self) -> Result<MachineModel, String> {
        MachineModel::parse(&self.to_text()?).map_err(|e| e.0)
    }

    /// The number at `key`, if present.
    pub fn number(&self, key: Key) -> Option<f64> {
        let v = self.section(key.section)?.get(key.name)?;
        v.as_float().or_else(|| v.as_integer().map(|i| i as f64))
    }

    /// Whether the section exists.
    pub fn has_section(&self, section: SectionKey) -> bool {
        self.section(section.0).is_some()
    }

    fn section(&self, path: &str) -> Option<&toml::Table> {
        path.split('.')
            .try_fold(&self.table, |t, part| t.get(part)?.as_table())
    }

    fn section_mut(&mut self, path: &str) -> Option<&mut toml::Table> {
        let mut t = &mut self.table;
        for part in path.split('.') {
            let entry = t
                .entry(part.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            t = entry.as_table_mut()?;
        }
        Some(t)
    }

    /// This document with `edits` applied.
    pub fn with(&self, edits: &[Edit]) -> Self {
        let mut d = self.clone();
        for e in edits {
            match e {
                Edit::Set(k, v) => {
                    if let Some(t) = d.section_mut(k.section) {
                        t.insert(k.name.to_string(), toml::Value::Float(*v));
                    }
                }
                Edit::SetBool(k, v) => {
                    if let Some(t) = d.section_mut(k.section) {
                        t.insert(k.name.to_string(), toml::Value::Boolean(*v));
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
                        let table: toml::Table = terms
                            .iter()
                            .map(|(k, v)| (k.to_string(), toml::Value::Float(*v)))
                            .collect();
                        t.insert("terms".into(), toml::Value::Table(table));
                        if let Some(p) = period_m {
                            t.insert("period_m".into(), toml::Value::Float(*p));
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
                        None => Some(&mut d.table),
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
}
