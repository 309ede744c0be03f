//! A CRS written as WKT (a PAM `.aux.xml` sidecar's `<SRS>`, an ESRI `.prj`)
//! turned into the GeoTIFF keys a file would carry for it, so a DSM
//! georeferenced beside the file is one [`Crs`] with the ones georeferenced
//! inside it: same EPSG code, same unit checks, same keys in the outputs.
//!
//! WKT 1 (OGC, GDAL, ESRI) and WKT 2 are read: the horizontal CRS (of a
//! compound or bound CRS too), its EPSG code (`AUTHORITY["EPSG","32617"]`,
//! `ID["EPSG",32617]`), its linear unit, and the vertical CRS's code and unit.
//! ESRI's WKT names no code: a Transverse Mercator CRS that is a UTM zone on
//! WGS 84, NAD83 or ETRS89 gets the zone's code, as GDAL identifies it
//! ([`identify_utm`]); any other CRS without a code is refused by name (its
//! definition cannot be compared with the other DSMs' safely).

use super::equivalent::identify_utm;
use super::geokeys::{crs_from_entries, key, GeoKeyValue, GeoKeys, METRE, USER_DEFINED};
use crate::geo::Crs;

/// One bracketed WKT node: `KEYWORD[arg, arg, ...]`.
#[derive(Clone, Debug, PartialEq)]
struct Node {
    keyword: String,
    args: Vec<Arg>,
}

#[derive(Clone, Debug, PartialEq)]
enum Arg {
    Text(String),
    Number(f64),
    /// An unquoted word that is not a node (`EAST`, `Cartesian`).
    Word(String),
    Node(Node),
}

impl Node {
    /// The first argument when it is quoted text (a node's name).
    fn name(&self) -> &str {
        match self.args.first() {
            Some(Arg::Text(t)) => t,
            _ => "",
        }
    }

    fn children(&self) -> impl Iterator<Item = &Node> {
        self.args.iter().filter_map(|a| match a {
            Arg::Node(n) => Some(n),
            _ => None,
        })
    }

    /// The first child whose keyword is one of `keywords` (any case).
    fn child(&self, keywords: &[&str]) -> Option<&Node> {
        self.children()
            .find(|n| keywords.iter().any(|k| n.keyword.eq_ignore_ascii_case(k)))
    }

    fn number(&self, i: usize) -> Option<f64> {
        match self.args.get(i)? {
            Arg::Number(v) => Some(*v),
            Arg::Text(t) => t.trim().parse().ok(),
            _ => None,
        }
    }

    /// `AUTHORITY["EPSG","32617"]` (WKT 1) or `ID["EPSG",32617]` (WKT 2).
    fn epsg(&self) -> Option<u32> {
        let id = self.child(&["AUTHORITY", "ID"])?;
        if !id.name().eq_ignore_ascii_case("EPSG") {
            return None;
        }
        let code = id.number(1)?;
        (code >= 1.0 && code.fract() == 0.0 && code < f64::from(u32::MAX)).then_some(code as u32)
    }

    /// Metres per unit of the node's length unit: its own `UNIT` /
    /// `LENGTHUNIT`, else the first axis's (WKT 2 may put it there).
    fn metres_per_unit(&self) -> Option<f64> {
        let unit = self.child(&["UNIT", "LENGTHUNIT"]).or_else(|| {
            self.children()
                .filter(|n| n.keyword.eq_ignore_ascii_case("AXIS"))
                .find_map(|a| a.child(&["UNIT", "LENGTHUNIT"]))
        })?;
        unit.number(1)
    }
}

/// Parse WKT text into its top node; `Err` says where it stops making sense.
fn parse(text: &str) -> Result<Node, String> {
    let mut p = Parser {
        chars: text.trim().chars().collect(),
        at: 0,
        depth: 0,
    };
    let node = p.node()?;
    p.skip_space();
    if p.at != p.chars.len() {
        return Err(format!("text after the WKT at character {}", p.at));
    }
    Ok(node)
}

struct Parser {
    chars: Vec<char>,
    at: usize,
    depth: usize,
}

/// Deeper nesting than any CRS has (a compound of bound projected CRSs is
/// about 8): a file nested deeper is not WKT, and the parser's recursion
/// stays far from the stack's end.
const MAX_DEPTH: usize = 64;

impl Parser {
    fn skip_space(&mut self) {
        while self.chars.get(self.at).is_some_and(|c| c.is_whitespace()) {
            self.at += 1;
        }
    }

    fn word(&mut self) -> String {
        self.skip_space();
        let start = self.at;
        while (self.chars.get(self.at))
            .is_some_and(|c| c.is_alphanumeric() || matches!(c, '_' | '.' | '-' | '+'))
        {
            self.at += 1;
        }
        self.chars[start..self.at].iter().collect()
    }

    fn node(&mut self) -> Result<Node, String> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(format!("nested deeper than {MAX_DEPTH} levels"));
        }
        let node = self.node_body();
        self.depth -= 1;
        node
    }

    fn node_body(&mut self) -> Result<Node, String> {
        let keyword = self.word();
        if keyword.is_empty() || !keyword.starts_with(|c: char| c.is_alphabetic()) {
            return Err(format!("expected a WKT keyword at character {}", self.at));
        }
        self.skip_space();
        let close = match self.chars.get(self.at) {
            Some('[') => ']',
            Some('(') => ')',
            _ => return Err(format!("expected '[' after {keyword}")),
        };
        self.at += 1;
        let mut args = Vec::new();
        loop {
            self.skip_space();
            match self.chars.get(self.at) {
                Some(c) if *c == close && args.is_empty() => {
                    self.at += 1;
                    break;
                }
                None => return Err(format!("{keyword}[ is not closed")),
                _ => {}
            }
            args.push(self.arg()?);
            self.skip_space();
            match self.chars.get(self.at) {
                Some(',') => self.at += 1,
                Some(c) if *c == close => {
                    self.at += 1;
                    break;
                }
                _ => return Err(format!("expected ',' or '{close}' in {keyword}[")),
            }
        }
        Ok(Node { keyword, args })
    }

    fn arg(&mut self) -> Result<Arg, String> {
        self.skip_space();
        match self.chars.get(self.at) {
            Some('"') => {
                self.at += 1;
                let mut text = String::new();
                loop {
                    match self.chars.get(self.at) {
                        None => return Err("a quoted text is not closed".into()),
                        // WKT 2 writes a quote inside text as two
                        Some('"') if self.chars.get(self.at + 1) == Some(&'"') => {
                            text.push('"');
                            self.at += 2;
                        }
                        Some('"') => {
                            self.at += 1;
                            return Ok(Arg::Text(text));
                        }
                        Some(c) => {
                            text.push(*c);
                            self.at += 1;
                        }
                    }
                }
            }
            Some(c) if c.is_ascii_digit() || matches!(c, '-' | '+' | '.') => {
                let word = self.word();
                word.parse()
                    .map(Arg::Number)
                    .map_err(|_| format!("{word:?} is not a number"))
            }
            _ => {
                let start = self.at;
                let word = self.word();
                self.skip_space();
                if matches!(self.chars.get(self.at), Some('[' | '(')) {
                    self.at = start;
                    self.node().map(Arg::Node)
                } else if word.is_empty() {
                    Err(format!("unexpected character at {}", self.at))
                } else {
                    Ok(Arg::Word(word))
                }
            }
        }
    }
}

/// EPSG unit codes of the feet GeoTIFF keys name.
const FOOT: (f64, u16) = (0.3048, 9002);
const US_SURVEY_FOOT: (f64, u16) = (0.304_800_609_601_219_2, 9003);

/// The GeoKey value of a length unit of `m` metres: the EPSG unit code when
/// there is one, else `None` (a size GeoTIFF keys give only horizontally).
fn unit_code(m: f64) -> Option<u16> {
    [(1.0, METRE), FOOT, US_SURVEY_FOOT]
        .iter()
        .find(|(size, _)| (m - size).abs() <= 1e-9)
        .map(|&(_, code)| code)
}

fn is(node: &Node, keywords: &[&str]) -> bool {
    keywords
        .iter()
        .any(|k| node.keyword.eq_ignore_ascii_case(k))
}

const PROJECTED: [&str; 3] = ["PROJCS", "PROJCRS", "PROJECTEDCRS"];
const GEOGRAPHIC: [&str; 6] = [
    "GEOGCS",
    "GEOGCRS",
    "GEOGRAPHICCRS",
    "GEODCRS",
    "GEODETICCRS",
    "GEOCCS",
];
const VERTICAL: [&str; 3] = ["VERT_CS", "VERTCRS", "VERTICALCRS"];

/// The [`Crs`] of a WKT text; `Err` is one phrase saying what is missing or
/// not supported (the caller names the file).
pub fn crs_from_wkt(text: &str) -> Result<Crs, String> {
    let top = parse(text).map_err(|e| format!("CRS is not WKT ({e})"))?;
    let (horizontal, vertical) = horizontal_and_vertical(top)?;
    let mut entries: Vec<(u16, GeoKeyValue)> = vec![(key::GT_RASTER_TYPE, GeoKeyValue::Short(1))];
    if is(&horizontal, &PROJECTED) {
        entries.extend(projected_keys(&horizontal)?);
    } else if is(&horizontal, &GEOGRAPHIC) {
        let code = (horizontal.epsg())
            .and_then(|c| u16::try_from(c).ok())
            .unwrap_or(USER_DEFINED);
        entries.push((key::GT_MODEL_TYPE, GeoKeyValue::Short(2)));
        entries.push((key::GEOGRAPHIC_TYPE, GeoKeyValue::Short(code)));
        // ESRI's GEOGCS names no code: its datum, when one of the three
        // whose longitudes and latitudes ingest puts into UTM
        if let Some(datum) = (code == USER_DEFINED)
            .then(|| datum_code(&horizontal))
            .flatten()
            .and_then(|c| u16::try_from(c).ok())
        {
            entries.push((2050, GeoKeyValue::Short(datum)));
        }
    } else {
        return Err(format!(
            "CRS {} \"{}\" is not a projected CRS",
            horizontal.keyword,
            horizontal.name()
        ));
    }
    if let Some(v) = vertical {
        entries.extend(vertical_keys(&v)?);
    }
    entries.push((
        key::GT_CITATION,
        GeoKeyValue::Ascii(horizontal.name().to_string()),
    ));
    crs_from_entries(entries).map_err(|e| e.to_string())
}

/// The EPSG code of a WKT CRS's horizontal part (of a compound or bound CRS
/// too): its own code, or the UTM zone ESRI's Transverse Mercator defines;
/// `None` for text that is not WKT or a CRS without one.
pub fn epsg(text: &str) -> Option<u32> {
    let horizontal = horizontal_and_vertical(parse(text.trim_end_matches('\0')).ok()?)
        .ok()?
        .0;
    horizontal.epsg().or_else(|| {
        let metres = horizontal.metres_per_unit().unwrap_or(1.0);
        is(&horizontal, &PROJECTED)
            .then(|| utm_code(&horizontal, metres).or_else(|| grid_code(&horizontal, metres)))
            .flatten()
    })
}

/// The units of length other than the metre a WKT CRS names: the `UNIT` of a
/// projected, vertical, local or geocentric CRS (not the angle unit of its
/// geographic base), every WKT 2 `LENGTHUNIT`; e.g. "unit US survey foot
/// (0.304800609601219 m)". Empty for text that is not WKT.
pub fn non_metre_units(text: &str) -> Vec<String> {
    const LENGTH_PARENTS: [&str; 5] = ["PROJCS", "VERT_CS", "LOCAL_CS", "GEOCCS", "VERTCS"];
    fn walk(node: &Node, found: &mut Vec<String>) {
        for child in node.children() {
            let length =
                is(child, &["LENGTHUNIT"]) || (is(child, &["UNIT"]) && is(node, &LENGTH_PARENTS));
            if let Some(factor) = child.number(1).filter(|f| length && (f - 1.0).abs() > 1e-9) {
                let unit = format!("unit {} ({factor} m)", child.name());
                if !found.contains(&unit) {
                    found.push(unit);
                }
            }
            walk(child, found);
        }
    }
    let mut found = Vec::new();
    if let Ok(top) = parse(text.trim_end_matches('\0')) {
        walk(&top, &mut found);
    }
    found
}

/// A CRS's horizontal part and, for a compound CRS, its vertical part; a
/// bound CRS (WKT 2, with a transformation to WGS 84) gives its source CRS's.
fn horizontal_and_vertical(mut top: Node) -> Result<(Node, Option<Node>), String> {
    if is(&top, &["BOUNDCRS"]) {
        top = (top.child(&["SOURCECRS"]))
            .and_then(|s| s.children().next())
            .cloned()
            .ok_or("BOUNDCRS without a SOURCECRS")?;
    }
    if is(&top, &["COMPD_CS", "COMPOUNDCRS"]) {
        let mut parts = top.children().filter(|n| !is(n, &["AUTHORITY", "ID"]));
        let h = parts.next().ok_or("a compound CRS without parts")?.clone();
        Ok((h, parts.find(|n| is(n, &VERTICAL)).cloned()))
    } else {
        Ok((top, None))
    }
}

/// Model, code and unit keys of a projected CRS: its EPSG code, or the UTM
/// zone its Transverse Mercator parameters define.
fn projected_keys(crs: &Node) -> Result<Vec<(u16, GeoKeyValue)>, String> {
    let metres = crs.metres_per_unit().unwrap_or(1.0);
    let code = match crs.epsg() {
        Some(code) => code,
        None => (utm_code(crs, metres).or_else(|| grid_code(crs, metres))).ok_or_else(|| {
            format!(
                "CRS \"{}\" names no EPSG code and is neither a UTM zone nor a grid dsmstream knows on WGS 84, NAD83 or ETRS89: assign its code, e.g. gdal_edit.py -a_srs EPSG:nnnn",
                crs.name()
            )
        })?,
    };
    let code = u16::try_from(code).map_err(|_| {
        format!(
            "CRS \"{}\" has code EPSG:{code}, beyond GeoTIFF's codes",
            crs.name()
        )
    })?;
    let mut keys = vec![
        (key::GT_MODEL_TYPE, GeoKeyValue::Short(1)),
        (key::PROJECTED_CS_TYPE, GeoKeyValue::Short(code)),
    ];
    match unit_code(metres) {
        Some(METRE) => {}
        Some(unit) => keys.push((key::PROJ_LINEAR_UNITS, GeoKeyValue::Short(unit))),
        None => {
            keys.push((key::PROJ_LINEAR_UNITS, GeoKeyValue::Short(USER_DEFINED)));
            keys.push((
                key::PROJ_LINEAR_UNIT_SIZE,
                GeoKeyValue::Doubles(vec![metres]),
            ));
        }
    }
    Ok(keys)
}

/// The EPSG code of a UTM zone written as Transverse Mercator (ESRI's WKT).
fn utm_code(crs: &Node, metres: f64) -> Option<u32> {
    // WKT 1 puts the method and parameters in the CRS, WKT 2 in its CONVERSION
    let conversion = crs.child(&["CONVERSION"]).unwrap_or(crs);
    let method = (crs.child(&["PROJECTION"]))
        .or_else(|| conversion.child(&["METHOD"]))?
        .name();
    if normalised(method) != "transverse_mercator" || unit_code(metres) != Some(METRE) {
        return None;
    }
    let mut params: Vec<(u16, f64)> = Vec::new();
    for p in conversion.children().filter(|n| is(n, &["PARAMETER"])) {
        let id = match normalised(p.name()).as_str() {
            "latitude_of_origin" | "latitude_of_natural_origin" => 3081,
            "central_meridian" | "longitude_of_natural_origin" => 3080,
            "scale_factor" | "scale_factor_at_natural_origin" => 3092,
            "false_easting" => 3082,
            "false_northing" => 3083,
            _ => continue,
        };
        params.push((id, p.number(1)?));
    }
    let geographic = crs
        .child(&GEOGRAPHIC)
        .or_else(|| crs.child(&["BASEGEOGCRS", "BASEGEODCRS"]))?;
    let datum_code = datum_code(geographic)?;
    let mut entries = vec![
        (key::GT_MODEL_TYPE, GeoKeyValue::Short(1)),
        (key::PROJECTED_CS_TYPE, GeoKeyValue::Short(USER_DEFINED)),
        (key::PROJ_COORD_TRANS, GeoKeyValue::Short(1)),
        (key::PROJ_LINEAR_UNITS, GeoKeyValue::Short(METRE)),
        (2050, GeoKeyValue::Short(u16::try_from(datum_code).ok()?)),
    ];
    entries.extend(
        params
            .into_iter()
            .map(|(id, v)| (id, GeoKeyValue::Doubles(vec![v]))),
    );
    identify_utm(&GeoKeys { entries })
}

/// The EPSG code of a national or polar grid written without one (ESRI's
/// WKT): its method, parameters and datum matched to the grids of
/// [`crate::geo::proj::identify`].
fn grid_code(crs: &Node, metres: f64) -> Option<u32> {
    if unit_code(metres) != Some(METRE) {
        return None;
    }
    let conversion = crs.child(&["CONVERSION"]).unwrap_or(crs);
    let method = (crs.child(&["PROJECTION"]))
        .or_else(|| conversion.child(&["METHOD"]))?
        .name();
    let params: Vec<(String, f64)> = (conversion.children())
        .filter(|n| is(n, &["PARAMETER"]))
        .filter_map(|p| Some((normalised(p.name()), p.number(1)?)))
        .collect();
    let geographic = crs
        .child(&GEOGRAPHIC)
        .or_else(|| crs.child(&["BASEGEOGCRS", "BASEGEODCRS"]))?;
    // WGS 84, NAD83 or ETRS89 (one datum to the grids)
    datum_code(geographic).filter(|c| [6326, 6269, 6258].contains(c))?;
    crate::geo::proj::identify(&normalised(method), &params)
}

/// The EPSG code of a geographic CRS's datum: its own, or by the name GDAL
/// or ESRI give WGS 84, NAD83 and ETRS89 (RGF93 and SWEREF99, realisations
/// of ETRS89, count as ETRS89, as in [`crate::geo::proj`]).
fn datum_code(geographic: &Node) -> Option<u32> {
    let datum = geographic.child(&["DATUM"])?;
    datum
        .epsg()
        .or_else(|| match normalised(datum.name()).trim_start_matches("d_") {
            "wgs_1984" | "world_geodetic_system_1984" => Some(6326),
            "north_american_1983" | "north_american_datum_1983" => Some(6269),
            "etrs_1989" | "european_terrestrial_reference_system_1989" => Some(6258),
            "rgf_1993" | "reseau_geodesique_francais_1993" | "sweref99" => Some(6258),
            _ => None,
        })
}

/// The vertical CRS's code and unit keys.
fn vertical_keys(crs: &Node) -> Result<Vec<(u16, GeoKeyValue)>, String> {
    let mut keys = Vec::new();
    if let Some(code) = crs.epsg().and_then(|c| u16::try_from(c).ok()) {
        keys.push((key::VERTICAL_CS_TYPE, GeoKeyValue::Short(code)));
    }
    let metres = crs.metres_per_unit().unwrap_or(1.0);
    match unit_code(metres) {
        Some(METRE) => {}
        Some(unit) => keys.push((key::VERTICAL_UNITS, GeoKeyValue::Short(unit))),
        None => {
            return Err(format!(
                "vertical CRS \"{}\" has a unit of {metres} m, not metres",
                crs.name()
            ))
        }
    }
    Ok(keys)
}

/// Lower case, spaces and dashes as underscores: how ESRI and OGC names compare.
fn normalised(name: &str) -> String {
    name.trim().to_ascii_lowercase().replace([' ', '-'], "_")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geotiff::geokeys::non_metre_units as crs_non_metre_units;
    use proptest::prelude::*;

    proptest! {
        /// Any text, and any cut or splice of a real WKT, gives a CRS or an
        /// error: never a panic.
        #[test]
        fn any_text_is_a_crs_or_an_error(
            cut in 0usize..800,
            splice in "[\\[\\]\",A-Z0-9._ -]{0,12}",
            text in "\\PC{0,64}",
        ) {
            let at = GDAL_UTM17.char_indices().map(|(i, _)| i).nth(cut).unwrap_or(GDAL_UTM17.len());
            let spliced = format!("{}{splice}{}", &GDAL_UTM17[..at], &GDAL_UTM17[at..]);
            for t in [&GDAL_UTM17[..at], spliced.as_str(), text.as_str()] {
                let _ = crs_from_wkt(t);
                let _ = epsg(t);
                let _ = non_metre_units(t);
            }
        }
    }

    /// What GDAL 3.10 writes into a PAM sidecar for EPSG:32617.
    const GDAL_UTM17: &str = r#"PROJCS["WGS 84 / UTM zone 17N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",-81],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","32617"]]"#;

    /// What GDAL 3.10 writes as ESRI WKT (a `.prj`) for EPSG:32617: no codes.
    const ESRI_UTM17: &str = r#"PROJCS["WGS_1984_UTM_Zone_17N",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["False_Easting",500000.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-81.0],PARAMETER["Scale_Factor",0.9996],PARAMETER["Latitude_Of_Origin",0.0],UNIT["Meter",1.0]]"#;

    #[test]
    fn gdal_and_esri_wkt_of_one_utm_zone_are_one_crs() {
        let gdal = crs_from_wkt(GDAL_UTM17).unwrap();
        let esri = crs_from_wkt(ESRI_UTM17).unwrap();
        assert_eq!((gdal.epsg, gdal.is_geographic), (Some(32617), false));
        assert_eq!(esri.epsg, Some(32617));
        assert!(gdal.same_as(&esri));
        assert!(crs_non_metre_units(&gdal).is_empty());
        assert_eq!(gdal.label(), "EPSG:32617");
    }

    #[test]
    fn wkt2_compound_and_bound_crs_give_their_parts() {
        let wkt2 = r#"COMPOUNDCRS["ETRS89 / UTM 32N + DHHN2016",
            PROJCRS["ETRS89 / UTM zone 32N",BASEGEOGCRS["ETRS89",DATUM["European Terrestrial Reference System 1989",ELLIPSOID["GRS 1980",6378137,298.257222101]]],
              CONVERSION["UTM zone 32N",METHOD["Transverse Mercator",ID["EPSG",9807]]],
              CS[Cartesian,2],AXIS["easting (E)",east,LENGTHUNIT["metre",1]],AXIS["northing (N)",north,LENGTHUNIT["metre",1]],ID["EPSG",25832]],
            VERTCRS["DHHN2016 height",VDATUM["Deutsches Haupthoehennetz 2016"],CS[vertical,1],AXIS["gravity-related height (H)",up,LENGTHUNIT["metre",1]],ID["EPSG",7837]]]"#;
        let crs = crs_from_wkt(wkt2).unwrap();
        assert_eq!(crs.epsg, Some(25832));
        assert!(crs_non_metre_units(&crs).is_empty());
        let keys = GeoKeys::parse(
            &crs.geokeys,
            &crs.geo_doubles,
            crs.geo_ascii.as_deref().unwrap(),
        )
        .unwrap();
        assert_eq!(keys.short(key::VERTICAL_CS_TYPE), Some(7837));
        let bound = format!(
            r#"BOUNDCRS[SOURCECRS[{GDAL_UTM17}],TARGETCRS[GEOGCRS["WGS 84"]],ABRIDGEDTRANSFORMATION["x",METHOD["Geocentric translations"]]]"#
        );
        assert_eq!(crs_from_wkt(&bound).unwrap().epsg, Some(32617));
    }

    #[test]
    fn feet_geographic_and_unknown_crs_are_told_apart() {
        let feet = GDAL_UTM17.replace(
            r#"UNIT["metre",1,AUTHORITY["EPSG","9001"]]"#,
            r#"UNIT["US survey foot",0.304800609601219]"#,
        );
        let units = crs_non_metre_units(&crs_from_wkt(&feet).unwrap());
        assert!(units[0].contains("US survey foot"), "{units:?}");
        let geographic = crs_from_wkt(r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4326"]]"#).unwrap();
        assert_eq!(
            (geographic.epsg, geographic.is_geographic),
            (Some(4326), true)
        );
        // ESRI's WGS 84 names no code: its datum, by name, is what ingest
        // needs to put it into UTM; an unknown datum stays unknown
        let esri = r#"GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]"#;
        let esri = crs_from_wkt(esri).unwrap();
        assert!(esri.is_geographic && esri.epsg.is_none());
        assert_eq!(
            crate::geotiff::equivalent::geographic_datum(&esri),
            Some(crate::geo::tm::Datum::Wgs84)
        );
        let ed50 = crs_from_wkt(r#"GEOGCS["GCS_European_1950",DATUM["D_European_1950",SPHEROID["International_1924",6378388.0,297.0]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]"#).unwrap();
        assert_eq!(crate::geotiff::equivalent::geographic_datum(&ed50), None);
        // an ESRI CRS that is no UTM zone has no code to compare by
        let lambert = ESRI_UTM17.replace("Transverse_Mercator", "Lambert_Conformal_Conic");
        assert!(crs_from_wkt(&lambert)
            .unwrap_err()
            .contains("names no EPSG code"));
        let off_zone = ESRI_UTM17.replace("-81.0", "-80.0");
        assert!(crs_from_wkt(&off_zone).is_err());
        let vert_feet = format!(
            r#"COMPD_CS["x",{GDAL_UTM17},VERT_CS["NAVD88 height (ftUS)",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["US survey foot",0.304800609601219],AUTHORITY["EPSG","6360"]]]"#
        );
        let units = crs_non_metre_units(&crs_from_wkt(&vert_feet).unwrap());
        assert!(units.iter().any(|u| u.contains("height unit")), "{units:?}");
    }

    #[test]
    fn epsg_of_projected_wkt() {
        let wkt1 = r#"PROJCS["NAD83 / UTM zone 17N",GEOGCS["NAD83",AUTHORITY["EPSG","4269"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","26917"]]"#;
        assert_eq!(epsg(wkt1), Some(26917));
        let compound = r#"COMPD_CS["x",PROJCS["WGS 84 / UTM zone 16N",GEOGCS["WGS 84",AUTHORITY["EPSG","4326"]],AUTHORITY["EPSG","32616"]],VERT_CS["NAVD88",AUTHORITY["EPSG","5703"]]]"#;
        assert_eq!(epsg(compound), Some(32616));
        let wkt2 = r#"PROJCRS["WGS 84 / UTM zone 16N",BASEGEOGCRS["WGS 84",ID["EPSG",4326]],ID["EPSG",32616]]"#;
        assert_eq!(epsg(wkt2), Some(32616));
        assert_eq!(epsg("LOCAL_CS[\"x\"]"), None);
        let no_own = r#"PROJCS["x",GEOGCS["WGS 84",AUTHORITY["EPSG","4326"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert_eq!(epsg(no_own), None);
        assert_eq!(epsg(&format!("{ESRI_UTM17}\0")), Some(32617));
        assert_eq!(epsg("PROJCS["), None);
    }

    #[test]
    fn wkt_units_of_length_but_not_angles() {
        let feet = r#"PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)",GEOGCS["NAD83(HARN)",UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]]"#;
        assert_eq!(non_metre_units(feet), ["unit foot (0.3048 m)"]);
        let utm = r#"PROJCS["WGS 84 / UTM zone 16N",GEOGCS["WGS 84",UNIT["degree",0.0174532925199433]],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert!(non_metre_units(utm).is_empty());
        let heights_in_feet = r#"COMPD_CS["x",PROJCS["UTM",GEOGCS["g",UNIT["degree",0.01745]],UNIT["metre",1]],VERT_CS["NAVD88 height (ftUS)",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["US survey foot",0.304800609601219]]]"#;
        assert_eq!(
            non_metre_units(heights_in_feet),
            ["unit US survey foot (0.304800609601219 m)"]
        );
        let wkt2 = r#"PROJCRS["x",BASEGEOGCRS["g",ANGLEUNIT["degree",0.0174532925199433]],CS[Cartesian,2],AXIS["easting",east,LENGTHUNIT["US survey foot",0.304800609601219]]]"#;
        assert_eq!(
            non_metre_units(wkt2),
            ["unit US survey foot (0.304800609601219 m)"]
        );
    }

    #[test]
    fn text_that_is_not_wkt_is_refused_with_where() {
        for bad in [
            "",
            "EPSG:32617",
            "PROJCS[\"x\"",
            "PROJCS[\"x\",UNIT[\"m\",1]] tail",
            "PROJCS[\"x\",1e]",
        ] {
            let e = crs_from_wkt(bad).unwrap_err();
            assert!(e.starts_with("CRS is not WKT"), "{bad}: {e}");
        }
        let deep = format!("{}{}", "PROJCS[\"x\",".repeat(100_000), "]".repeat(100_000));
        assert!(crs_from_wkt(&deep)
            .unwrap_err()
            .contains("nested deeper than 64"));
        assert!(crs_from_wkt(r#"LOCAL_CS["site grid"]"#)
            .unwrap_err()
            .contains("not a projected CRS"));
    }
}
