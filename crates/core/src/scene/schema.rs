//! The scene file's schema as serde reads it: a struct per table, and the forms each key
//! accepts. A table is a table only ([`Table`]: not serde's array of fields), and a key of
//! several forms names them all when a value fits none ([`NameOr`]). Validation is in
//! [`super::file`].

use serde::Deserialize;
use toml::Spanned;

use crate::Error;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileToml {
    #[serde(default)]
    pub(super) unit: Option<Spanned<String>>,
    #[serde(default)]
    pub(super) object: Vec<Spanned<Table<ObjectToml>>>,
    #[serde(default)]
    pub(super) finger: Vec<Spanned<Table<FingerToml>>>,
    #[serde(default)]
    pub(super) haptics: Option<Table<HapticsToml>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ObjectToml {
    pub(super) name: Option<String>,
    pub(super) mesh: Spanned<String>,
    pub(super) mesh_unit: Option<Spanned<String>>,
    pub(super) young: Option<Spanned<f64>>,
    pub(super) poisson: Option<Spanned<f64>>,
    pub(super) formulation: Option<Spanned<String>>,
    pub(super) fixed: Option<Spanned<String>>,
    pub(super) touchable: Option<Spanned<TouchableToml>>,
    pub(super) offset: Option<Spanned<[f64; 3]>>,
    pub(super) friction: Option<Spanned<Table<FrictionToml>>>,
    pub(super) cuttable: Option<Spanned<TouchableToml>>,
    pub(super) compression: Option<Spanned<Table<CompressionToml>>>,
    #[serde(default)]
    pub(super) region: Vec<Spanned<Table<RegionToml>>>,
}

/// `compression = { tolerance = 1e-3 }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CompressionToml {
    pub(super) tolerance: f64,
}

/// `friction = { static = 0.6, dynamic = 0.4 }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FrictionToml {
    #[serde(rename = "static")]
    pub(super) static_mu: f64,
    pub(super) dynamic: f64,
}

/// `tool = { sphere = R }` (R in the scene's unit).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ToolToml {
    pub(super) sphere: Option<f64>,
    pub(super) blade: Option<f64>,
}

/// `[[object.region]]`: the tets of a physical volume group, of another material.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RegionToml {
    pub(super) group: Spanned<String>,
    pub(super) young: Spanned<f64>,
    pub(super) poisson: Option<Spanned<f64>>,
}

/// `touchable` or `cuttable`: `"all"`, a group's name, or a ball.
#[derive(Debug)]
pub(super) enum TouchableToml {
    Name(String),
    Ball(BallToml),
}

impl<'de> Deserialize<'de> for TouchableToml {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        NameOr::read(
            d,
            "\"all\", a group's name, or a ball { center = [x, y, z], radius = r }",
            TouchableToml::Name,
            TouchableToml::Ball,
        )
    }
}

/// A visitor for a value that is a string or a table of `T`: `Ok(string)` or `Err(table)`;
/// anything else is an error naming the accepted forms (not serde's "did not match any variant
/// of untagged enum").
pub(super) struct NameOr<T> {
    pub(super) expected: &'static str,
    pub(super) table: std::marker::PhantomData<T>,
}

impl<T> NameOr<T> {
    /// Reads a string or a table of `T` from `d` (`expected` names both forms), made into a
    /// `V` by `name` or by `table`.
    fn read<'de, D: serde::Deserializer<'de>, V>(
        d: D,
        expected: &'static str,
        name: impl FnOnce(String) -> V,
        table: impl FnOnce(T) -> V,
    ) -> Result<V, D::Error>
    where
        T: Deserialize<'de>,
    {
        let v = d.deserialize_any(NameOr {
            expected,
            table: std::marker::PhantomData,
        })?;
        Ok(match v {
            Ok(s) => name(s),
            Err(t) => table(t),
        })
    }
}

impl<'de, T: Deserialize<'de>> serde::de::Visitor<'de> for NameOr<T> {
    type Value = Result<String, T>;
    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.expected)
    }
    fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Self::Value, E> {
        Ok(Ok(v.to_string()))
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, m: A) -> Result<Self::Value, A::Error> {
        T::deserialize(serde::de::value::MapAccessDeserializer::new(m)).map(Err)
    }
}

/// A table of the schema: a `T` written as a TOML table (`[x]`, `[[x]]` or `{ … }`) and
/// nothing else. serde's derived structs also take an array of their fields in order
/// (`friction = [0.6, 0.4]`), a form the schema does not have: that is refused here, with a
/// message naming the documented form ([`TableForm::FORM`]).
#[derive(Debug)]
pub(super) struct Table<T>(pub(super) T);

/// The documented form of a table of the schema, for messages.
pub(super) trait TableForm {
    /// E.g. `` a table `friction = { static = MS, dynamic = MD }` ``.
    const FORM: &'static str;
}

impl<T> std::ops::Deref for Table<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<'de, T: Deserialize<'de> + TableForm> Deserialize<'de> for Table<T> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de> + TableForm> serde::de::Visitor<'de> for V<T> {
            type Value = T;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(T::FORM)
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, m: A) -> Result<T, A::Error> {
                T::deserialize(serde::de::value::MapAccessDeserializer::new(m))
            }
        }
        d.deserialize_map(V(std::marker::PhantomData)).map(Table)
    }
}

/// `impl TableForm` for each table type, with its documented form.
macro_rules! table_forms {
    ($($t:ty => $form:literal,)*) => {
        $(impl TableForm for $t {
            const FORM: &'static str = $form;
        })*
    };
}
table_forms! {
    ObjectToml => "an `[[object]]` table",
    FingerToml => "a `[[finger]]` table",
    HapticsToml => "a `[haptics]` table",
    RegionToml => "an `[[object.region]]` table (group, young, poisson)",
    FrictionToml => "a table `friction = { static = MS, dynamic = MD }`",
    CompressionToml => "a table `compression = { tolerance = EPS }`",
    ToolToml => "a table `tool = { sphere = R }` or `tool = { blade = DEPTH }`",
    BallToml => "a ball { center = [x, y, z], radius = r }",
    LimitNumbersToml => "a table of limits (max_force_n, max_stiffness_n_per_m, …)",
    HaplyToml => "a table `haply = { url, device_id, device_centre, scene_centre, scale }`",
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct BallToml {
    pub(super) center: [f64; 3],
    pub(super) radius: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FingerToml {
    pub(super) device: Spanned<String>,
    pub(super) path: Option<Spanned<Vec<[f64; 4]>>>,
    pub(super) model: Option<Spanned<String>>,
    pub(super) limits: Option<Spanned<LimitsToml>>,
    pub(super) tool: Option<Spanned<Table<ToolToml>>>,
    pub(super) haply: Option<Spanned<Table<HaplyToml>>>,
}

/// A Haply finger's `haply` table (every key optional).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct HaplyToml {
    pub(super) url: Option<String>,
    pub(super) device_id: Option<String>,
    pub(super) device_centre: Option<[f64; 3]>,
    pub(super) scene_centre: Option<[f64; 3]>,
    pub(super) scale: Option<f64>,
}

/// A finger's device limits: a preset's name, or the numbers (SI, the unit in each key).
#[derive(Debug)]
pub(super) enum LimitsToml {
    Preset(String),
    Numbers(LimitNumbersToml),
}

impl<'de> Deserialize<'de> for LimitsToml {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        NameOr::read(
            d,
            "a preset's name (\"falcon\", …) or a table of limits \
             { max_force_n, max_stiffness_n_per_m, max_damping_ns_per_m, workspace_radius_m, … }",
            LimitsToml::Preset,
            LimitsToml::Numbers,
        )
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LimitNumbersToml {
    pub(super) name: Option<String>,
    pub(super) max_force_n: f64,
    pub(super) max_continuous_force_n: Option<f64>,
    pub(super) max_stiffness_n_per_m: f64,
    pub(super) max_damping_ns_per_m: f64,
    pub(super) workspace_radius_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct HapticsToml {
    pub(super) rate_hz: Option<Spanned<f64>>,
    pub(super) max_force_n: Option<Spanned<f64>>,
}

/// A TOML syntax or type error as one line: `LABEL: line L, column C, key `K`: MESSAGE` (the key
/// the last `KEY =` before the error on its line; the column counts characters from 1), in the
/// form of the scene's other errors (the `toml` crate's own text spans several lines).
pub(super) fn toml_error(label: &str, text: &str, e: &toml::de::Error) -> Error {
    let message = e.message().trim().replace('\n', "; ");
    let Some(span) = e.span() else {
        return Error::Body(format!("{label}: {message}"));
    };
    let start = span.start.min(text.len());
    let start = (0..=start)
        .rev()
        .find(|&i| text.is_char_boundary(i))
        .unwrap_or(0);
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let before = &text[line_start..start];
    let column = before.chars().count() + 1;
    // The key: the name before the last `=` of the line ahead of the error.
    let key = before.rfind('=').and_then(|eq| {
        let name = before[..eq].trim_end();
        let from = name
            .rfind(|c: char| !(c.is_alphanumeric() || "_-.\"".contains(c)))
            .map_or(0, |i| i + 1);
        let k = name[from..].trim_matches('"');
        (!k.is_empty()).then(|| k.to_string())
    });
    // Inside an inline table (`tool = { sphere = "x" }`), the key's full path: `tool.sphere`.
    let key = key.map(|k| {
        let mut path = open_tables(before);
        path.push(k);
        path.join(".")
    });
    Error::Body(match key {
        Some(k) if !message.contains(&format!("`{k}`")) => format!(
            "{label}: line {}, column {column}, key `{k}`: {message}",
            line_of(text, start)
        ),
        _ => format!(
            "{label}: line {}, column {column}: {message}",
            line_of(text, start)
        ),
    })
}

/// The keys of the inline tables still open at the end of `line` (`a = { b = { c` → `a`, `b`),
/// quoted strings skipped.
fn open_tables(line: &str) -> Vec<String> {
    let (mut open, mut segment, mut quote) = (Vec::new(), 0, None);
    for (i, c) in line.char_indices() {
        if let Some(q) = quote {
            if c == q {
                quote = None;
            }
            continue;
        }
        match c {
            '"' | '\'' => quote = Some(c),
            '{' => {
                let key = line[segment..i].rsplit_once('=').map_or("", |(k, _)| k);
                open.push(key.trim().trim_matches('"').to_string());
                segment = i + 1;
            }
            '}' => {
                open.pop();
                segment = i + 1;
            }
            ',' => segment = i + 1,
            _ => {}
        }
    }
    open.into_iter().filter(|k| !k.is_empty()).collect()
}

/// The 1-based line of a byte offset in `text`.
pub(super) fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}
