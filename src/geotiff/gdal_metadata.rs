//! GDAL's band metadata (the GDAL_METADATA TIFF tag, 42112): an XML list of
//! `<Item name=".." sample="N" role="..">value</Item>`. Band 1's `scale` and
//! `offset` make its stored values physical (raw * scale + offset, as GDAL's
//! `GetScale` / `GetOffset` and `gdal_translate -unscale`); its `unittype`
//! names their unit (`GetUnitType`, e.g. "m" or "ft").

/// What band 1's metadata says; `scale` 1 and `offset` 0 when it says nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct BandMetadata {
    pub scale: f64,
    pub offset: f64,
    pub unit: Option<String>,
}

impl Default for BandMetadata {
    fn default() -> Self {
        BandMetadata {
            scale: 1.0,
            offset: 0.0,
            unit: None,
        }
    }
}

impl BandMetadata {
    /// Band 1's (sample 0) scale, offset and unit from the tag's XML; items of
    /// other bands, dataset items and values that do not parse are ignored.
    pub fn parse(xml: &str) -> BandMetadata {
        let mut meta = BandMetadata::default();
        let mut rest = xml;
        while let Some(start) = rest.find("<Item") {
            rest = &rest[start + 5..];
            let Some(open_end) = rest.find('>') else {
                break;
            };
            let attributes = &rest[..open_end];
            let body = &rest[open_end + 1..];
            let Some(close) = body.find("</Item>") else {
                break;
            };
            let value = unescape(body[..close].trim());
            rest = &body[close..];
            if attribute(attributes, "sample").as_deref() != Some("0") {
                continue;
            }
            let role = attribute(attributes, "role")
                .or_else(|| attribute(attributes, "name"))
                .unwrap_or_default()
                .to_ascii_lowercase();
            match role.as_str() {
                "scale" => meta.scale = value.parse().unwrap_or(meta.scale),
                "offset" => meta.offset = value.parse().unwrap_or(meta.offset),
                "unittype" if !value.is_empty() => meta.unit = Some(value),
                _ => {}
            }
        }
        meta
    }

    /// True when stored values need `raw * scale + offset`.
    pub fn rescales(&self) -> bool {
        self.scale != 1.0 || self.offset != 0.0
    }

    /// The unit when it names a foot ("ft", "foot", "feet", "US survey foot",
    /// "ftUS"...): heights that are not metres.
    pub fn unit_in_feet(&self) -> Option<&str> {
        self.unit.as_deref().filter(|u| is_feet(u))
    }
}

/// True when a unit name names a foot: "ft", "foot", "feet", "US survey
/// foot", "ftUS", "us-ft"...
pub fn is_feet(unit: &str) -> bool {
    let u = unit.to_ascii_lowercase();
    u.starts_with("ft") || u.contains("foot") || u.contains("feet") || u.ends_with("ft")
}

/// The value of `name="..."` in an element's attributes.
fn attribute(attributes: &str, name: &str) -> Option<String> {
    let mut rest = attributes;
    while let Some(at) = rest.find(name) {
        let before = rest[..at].chars().last();
        let after = rest[at + name.len()..].trim_start();
        rest = &rest[at + name.len()..];
        if before.is_some_and(|c| !c.is_whitespace()) {
            continue;
        }
        let Some(after) = after.strip_prefix('=') else {
            continue;
        };
        let after = after.trim_start();
        let quote = after.chars().next()?;
        if quote != '"' && quote != '\'' {
            continue;
        }
        let value = &after[1..];
        return value.find(quote).map(|end| unescape(&value[..end]));
    }
    None
}

fn unescape(text: &str) -> String {
    text.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_one_scale_offset_and_unit_are_read() {
        let xml = r#"<GDALMetadata>
  <Item name="AREA_OR_POINT">Area</Item>
  <Item name="OFFSET" sample="0" role="offset">100</Item>
  <Item name="SCALE" sample="0" role="scale">0.01</Item>
  <Item name="UNITTYPE" sample="0" role="unittype">m</Item>
  <Item name="SCALE" sample="1" role="scale">7</Item>
</GDALMetadata>"#;
        let meta = BandMetadata::parse(xml);
        assert_eq!((meta.scale, meta.offset), (0.01, 100.0));
        assert_eq!(meta.unit.as_deref(), Some("m"));
        assert!(meta.rescales() && meta.unit_in_feet().is_none());
    }

    #[test]
    fn nothing_said_is_the_identity_and_feet_are_named() {
        let none = BandMetadata::parse("<GDALMetadata>\n</GDALMetadata>");
        assert_eq!(none, BandMetadata::default());
        assert!(!none.rescales());
        // what this crate's writer puts there: a description and a unit
        let ours = r#"<GDALMetadata><Item name="DESCRIPTION" sample="0" role="description">height</Item><Item name="UNITTYPE" sample="0" role="unittype">m</Item></GDALMetadata>"#;
        assert_eq!(BandMetadata::parse(ours).unit.as_deref(), Some("m"));
        for feet in ["ft", "US survey foot", "ftUS", "feet", "us-ft"] {
            let xml = format!(r#"<Item sample="0" role="unittype" name="UNITTYPE">{feet}</Item>"#);
            assert_eq!(
                BandMetadata::parse(&xml).unit_in_feet(),
                Some(feet),
                "{feet}"
            );
        }
        for metres in ["m", "metre", "meters", "metres above sea level"] {
            let xml =
                format!(r#"<Item name="UNITTYPE" sample="0" role="unittype">{metres}</Item>"#);
            assert_eq!(BandMetadata::parse(&xml).unit_in_feet(), None, "{metres}");
        }
        // a value that does not parse leaves the default
        let bad = r#"<Item name="SCALE" sample="0" role="scale">abc</Item>"#;
        assert_eq!(BandMetadata::parse(bad).scale, 1.0);
    }
}
