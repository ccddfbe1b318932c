//! Colours on the wire (SPEC §5): sRGB as `"#rrggbb"`, checked once when the parameters are
//! validated and carried typed from there on, so nothing parses them again at run time.

use serde::{Deserialize, Serialize};

use crate::ParamError;

/// An sRGB colour given as `"#rrggbb"` (either case). It keeps the spelling it was given, so the
/// resolved parameters echo the request (a pipeline that wants one spelling asks for
/// [`Color::lowercase`]); it serialises as that text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Color {
    srgb: [u8; 3],
    text: String,
}

impl Color {
    /// Parses `#rrggbb`; the error names `field`.
    pub fn parse(field: &str, s: &str) -> Result<Self, ParamError> {
        let err = || {
            ParamError::new(
                field,
                format!("expected a colour like \"#a0b1c2\", got {s:?}"),
            )
        };
        let h = s.strip_prefix('#').ok_or_else(err)?;
        if h.len() != 6 || !h.is_ascii() {
            return Err(err());
        }
        let byte = |i: usize| u8::from_str_radix(&h[i..i + 2], 16).map_err(|_| err());
        Ok(Self {
            srgb: [byte(0)?, byte(2)?, byte(4)?],
            text: s.to_string(),
        })
    }

    /// The colour of these sRGB bytes, spelled `#rrggbb` in lower case.
    pub fn from_srgb8(srgb: [u8; 3]) -> Self {
        Self {
            srgb,
            text: format!("#{:02x}{:02x}{:02x}", srgb[0], srgb[1], srgb[2]),
        }
    }

    /// The same colour spelled in lower case.
    pub fn lowercase(self) -> Self {
        Self::from_srgb8(self.srgb)
    }

    /// The sRGB bytes.
    pub fn srgb8(&self) -> [u8; 3] {
        self.srgb
    }

    /// The colour as given (`#rrggbb`).
    pub fn as_str(&self) -> &str {
        &self.text
    }
}

impl Serialize for Color {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.text)
    }
}

impl<'de> Deserialize<'de> for Color {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Color::parse("color", &s).map_err(|e| serde::de::Error::custom(e.detail))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_hex_and_keeps_the_spelling() {
        let c = Color::parse("rock_color", "#A0b1C2").unwrap();
        assert_eq!(c.srgb8(), [0xa0, 0xb1, 0xc2]);
        assert_eq!(c.as_str(), "#A0b1C2");
        assert_eq!(c.clone().lowercase().as_str(), "#a0b1c2");
        assert_eq!(serde_json::to_value(&c).unwrap(), "#A0b1C2");
        for bad in ["a0b1c2", "#a0b1c", "#a0b1c2d", "#g0b1c2", "#ä0b1c"] {
            let e = Color::parse("rock_color", bad).unwrap_err();
            assert_eq!(e.field, "rock_color", "{bad}");
        }
        let back: Color = serde_json::from_value(serde_json::json!("#010203")).unwrap();
        assert_eq!(back, Color::from_srgb8([1, 2, 3]));
        assert!(serde_json::from_value::<Color>(serde_json::json!("red")).is_err());
    }
}
