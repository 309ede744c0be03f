//! What GDAL reads about a band beyond its pixels: the GDAL_METADATA TIFF tag
//! (42112), an XML document of `<Item>`s. Dataset items have a name only;
//! band items carry `sample="0"` (band 1) and a role: `role="description"` is
//! the band description (`gdalinfo` "Description = height", rasterio
//! `descriptions`), `role="unittype"` its unit (`GetUnitType`).

/// Band 1's description and unit, and dataset-level `name = value` items.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GdalMetadata {
    pub band_description: Option<String>,
    pub band_unit: Option<String>,
    /// Dataset metadata items, written in this order.
    pub items: Vec<(String, String)>,
}

impl GdalMetadata {
    /// The tag's XML, or None when there is nothing to say.
    pub fn to_xml(&self) -> Option<String> {
        if self.band_description.is_none() && self.band_unit.is_none() && self.items.is_empty() {
            return None;
        }
        let mut xml = String::from("<GDALMetadata>\n");
        for (name, value) in &self.items {
            xml.push_str(&format!(
                "  <Item name=\"{}\">{}</Item>\n",
                escape(name),
                escape(value)
            ));
        }
        let band = [
            ("DESCRIPTION", "description", &self.band_description),
            ("UNITTYPE", "unittype", &self.band_unit),
        ];
        for (name, role, value) in band {
            if let Some(v) = value {
                xml.push_str(&format!(
                    "  <Item name=\"{name}\" sample=\"0\" role=\"{role}\">{}</Item>\n",
                    escape(v)
                ));
            }
        }
        xml.push_str("</GDALMetadata>");
        Some(xml)
    }
}

/// XML text and attribute escaping of the five predefined entities.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for ch in text.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_items_carry_sample_and_role() {
        let m = GdalMetadata {
            band_description: Some("height".into()),
            band_unit: Some("m".into()),
            items: vec![("FUSE_METHOD".into(), "a<b & \"c\"".into())],
        };
        let xml = m.to_xml().unwrap();
        assert!(xml.starts_with("<GDALMetadata>\n"));
        assert!(xml.contains("<Item name=\"FUSE_METHOD\">a&lt;b &amp; &quot;c&quot;</Item>"));
        assert!(xml.contains(
            "<Item name=\"DESCRIPTION\" sample=\"0\" role=\"description\">height</Item>"
        ));
        assert!(xml.contains("<Item name=\"UNITTYPE\" sample=\"0\" role=\"unittype\">m</Item>"));
        assert!(xml.ends_with("</GDALMetadata>"));
        assert_eq!(GdalMetadata::default().to_xml(), None);
    }
}
