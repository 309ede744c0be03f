use super::*;

/// (EPSG code, longitude, latitude, easting, northing): PROJ 9.5.1's answers
/// (pyproj 3.7.2, `Transformer.from_crs(geographic, code, always_xy=True)`,
/// from EPSG:4326, 4258 or 4269 by the CRS's datum).
const PROJ: [(u32, f64, f64, f64, f64); 48] = [
    (3413, -45.0, 70.0, 0.0000, -2187927.6493),
    (3413, -40.0, 72.5, 166468.2343, -1902740.6243),
    (3413, 10.0, 79.0, 978990.0424, -685496.2075),
    (3413, -60.0, 60.5, -845127.6986, -3154059.5102),
    (3413, 170.0, 80.0, -622858.2943, 889533.8315),
    (3976, 0.0, -70.0, 0.0000, 2187927.6493),
    (3976, 30.0, -75.0, 816939.7487, 1414981.1515),
    (3976, -120.0, -62.0, -2678242.9859, -1546284.3089),
    (3031, 0.0, -71.0, 0.0000, 2082760.1085),
    (3031, 100.0, -80.0, 1072632.3723, -189134.0276),
    (3031, -60.0, -65.0, -2388932.7669, 1379250.9760),
    (3995, 15.0, 78.0, 338644.9604, -1263840.1978),
    (3995, -150.0, 71.0, -1041380.0543, 1803723.1640),
    (3995, 90.0, 85.0, 543593.2981, -0.0000),
    (5041, 15.0, 86.0, 2114985.1307, 1570869.6503),
    (5041, -100.0, 88.0, 1781304.4623, 2038561.9239),
    (5042, 0.0, -85.0, 2000000.0000, 2555457.3914),
    (5042, 120.0, -87.0, 2288511.5875, 1833427.7573),
    (32661, 15.0, 86.0, 2114985.1307, 1570869.6503),
    (32761, 120.0, -87.0, 2288511.5875, 1833427.7573),
    (3573, -100.0, 80.0, 0.0000, -1115409.0510),
    (3573, 15.0, 78.0, 1212353.2603, 565329.6097),
    (6931, 15.0, 78.0, 346218.0483, -1292103.3466),
    (6931, -120.0, 60.0, -2866387.8131, 1654909.7755),
    (6932, 60.0, -70.0, 1924023.4274, 1110835.4437),
    (2154, 3.0, 46.5, 700000.0000, 6600000.0000),
    (2154, 2.35, 48.85, 652301.5648, 6861302.7259),
    (2154, 7.7, 43.7, 1078729.6482, 6300271.1507),
    (2154, -4.5, 48.4, 145709.7889, 6837422.0826),
    (3034, 10.0, 52.0, 4000000.0000, 2800000.0000),
    (3034, -9.0, 38.7, 2388228.9539, 1571771.7817),
    (3034, 25.0, 65.0, 4702783.0947, 4287022.9909),
    (3035, 10.0, 52.0, 4321000.0000, 3210000.0000),
    (3035, -9.0, 38.7, 2676732.1125, 1941329.0843),
    (3035, 25.0, 65.0, 5026876.8348, 4731029.9640),
    (3035, 40.5, 39.5, 6879715.3945, 2347795.2835),
    (3006, 18.0, 59.3, 670817.9156, 6577304.5670),
    (3006, 12.0, 56.0, 312928.5609, 6210141.3267),
    (3067, 25.0, 60.2, 389130.0421, 6675364.4952),
    (3067, 29.0, 68.0, 583597.3886, 7544217.2805),
    (5070, -96.0, 23.0, 0.0000, 0.0000),
    (5070, -122.4, 37.8, -2273032.7875, 1958176.3913),
    (5070, -70.0, 44.0, 2051976.7476, 2616782.4178),
    (3338, -154.0, 50.0, 0.0000, 0.0000),
    (3338, -150.0, 61.2, 214143.6399, 1252955.5051),
    (3338, -165.0, 65.0, -516561.2851, 1713932.9876),
    (3571, 180.0, 75.0, 0.0000, -1670250.0136),
    (3571, -170.0, 66.0, 461834.0149, -2619190.8522),
];

#[test]
fn every_crs_of_the_table_projects_as_proj_does_both_ways() {
    for &(code, lon, lat, e, n) in &PROJ {
        let crs = ProjectedCrs::from_epsg(code).unwrap();
        let (x, y) = crs.projection.forward(lon, lat);
        assert!(
            (x - e).abs() < 1e-3 && (y - n).abs() < 1e-3,
            "EPSG:{code} ({lon}, {lat}): ({x:.4}, {y:.4}) against PROJ's ({e}, {n})"
        );
        let (lon2, lat2) = crs.projection.inverse(e, n);
        let dlon = (lon2 - lon + 540.0).rem_euclid(360.0) - 180.0;
        // 1e-9 degrees is 0.1 mm; at a pole longitude is undefined
        assert!(
            (lat2 - lat).abs() < 1e-9 && (dlon * lat.to_radians().cos()).abs() < 1e-9,
            "EPSG:{code} inverse of ({e}, {n}): ({lon2}, {lat2}) against ({lon}, {lat})"
        );
    }
    let codes: std::collections::BTreeSet<u32> = PROJ.iter().map(|p| p.0).collect();
    for entry in &TABLE {
        assert!(
            codes.contains(&entry.epsg),
            "EPSG:{} has no PROJ reference",
            entry.epsg
        );
    }
}

#[test]
fn round_trips_hold_across_each_crs_area() {
    for entry in &TABLE {
        let crs = ProjectedCrs::from_epsg(entry.epsg).unwrap();
        for k in 0..200 {
            let lon = entry.lon0 - 20.0 + 0.2 * k as f64;
            let lat = match entry.method {
                Method::PolarStereographicA { north: false, .. } => -80.0 + 0.05 * k as f64,
                Method::PolarStereographicB { lat_ts } if lat_ts < 0.0 => -85.0 + 0.1 * k as f64,
                Method::LambertAzimuthal { lat0, .. } if lat0 < 0.0 => -85.0 + 0.1 * k as f64,
                _ => 45.0 + 0.2 * k as f64,
            };
            let (e, n) = crs.projection.forward(lon, lat);
            let (lon2, lat2) = crs.projection.inverse(e, n);
            let dlon = (lon2 - lon + 540.0).rem_euclid(360.0) - 180.0;
            assert!(
                (lat2 - lat).abs() < 1e-10 && (dlon * lat.to_radians().cos()).abs() < 1e-10,
                "EPSG:{} ({lon}, {lat}) -> ({e}, {n}) -> ({lon2}, {lat2})",
                entry.epsg
            );
        }
    }
}

#[test]
fn the_scale_error_is_zero_on_standard_lines_and_grows_away_from_them() {
    let ps = ProjectedCrs::from_epsg(3413).unwrap().projection;
    let wgs84 = Ellipsoid::WGS84;
    assert!(ps.scale_error(wgs84, -45.0, 70.0) < 1e-6);
    let at_60 = ps.scale_error(wgs84, 10.0, 60.0);
    assert!((0.03..0.05).contains(&at_60), "{at_60}");
    let lcc = ProjectedCrs::from_epsg(2154).unwrap().projection;
    assert!(lcc.scale_error(Ellipsoid::GRS80, 7.0, 49.0) < 1e-6);
    let utm = ProjectedCrs::from_epsg(32637).unwrap().projection;
    let at_15 = utm.scale_error(wgs84, 39.0 + 15.0, 0.0);
    assert!((at_15 - 0.0354).abs() < 5e-4, "{at_15}");
    // equal area: one axis stretched as the other shrinks
    let albers = ProjectedCrs::from_epsg(5070).unwrap().projection;
    assert!(albers.scale_error(Ellipsoid::GRS80, -96.0, 37.5) > 1e-3);
}

#[test]
fn every_grid_written_as_esri_wkt_is_identified_by_its_code() {
    for (code, wkt) in ESRI {
        let crs = crate::geotiff::wkt::crs_from_wkt(wkt).unwrap();
        let found = crate::geotiff::equivalent::code(&crs);
        // UPS (N,E) and (E,N) define one projection: the first of the table;
        // SWEREF99 TM and TM35FIN are ETRS89's UTM 33N and 35N, parameter for
        // parameter, and a WKT without a code is identified as the zone
        let want = match code {
            32661 => 5041,
            32761 => 5042,
            3006 => 25833,
            3067 => 25835,
            _ => code,
        };
        assert_eq!(found, Some(want), "{wkt}");
    }
    // a parameter off, or another datum: no code
    let (_, lambert93) = ESRI.iter().find(|(c, _)| *c == 2154).unwrap();
    for changed in [
        lambert93.replace("700000.0", "700001.0"),
        lambert93.replace("D_RGF_1993", "D_NTF"),
        lambert93.replace("Lambert_Conformal_Conic", "Albers"),
    ] {
        assert!(
            crate::geotiff::wkt::crs_from_wkt(&changed).is_err(),
            "{changed}"
        );
    }
}
/// ESRI's WKT of each grid of the table (PROJ 9.5.1, pyproj 3.7.2:
/// `CRS.from_epsg(code).to_wkt("WKT1_ESRI")`), which names no code.
const ESRI: [(u32, &str); 19] = [
    (
        3413,
        r#"PROJCS["WGS_1984_NSIDC_Sea_Ice_Polar_Stereographic_North",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic_North_Pole"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-45.0],PARAMETER["Standard_Parallel_1",70.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3976,
        r#"PROJCS["WGS_1984_NSIDC_Sea_Ice_Polar_Stereographic_South",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic_South_Pole"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Standard_Parallel_1",-70.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3031,
        r#"PROJCS["WGS_1984_Antarctic_Polar_Stereographic",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic_South_Pole"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Standard_Parallel_1",-71.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3995,
        r#"PROJCS["WGS_1984_Arctic_Polar_Stereographic",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic_North_Pole"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Standard_Parallel_1",71.0],UNIT["Meter",1.0]]"#,
    ),
    (
        5041,
        r#"PROJCS["WGS_1984_UPS_North_(E-N)",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Polar_Stereographic_Variant_A"],PARAMETER["False_Easting",2000000.0],PARAMETER["False_Northing",2000000.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Scale_Factor",0.994],PARAMETER["Latitude_Of_Origin",90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        5042,
        r#"PROJCS["WGS_1984_UPS_South_(E-N)",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Polar_Stereographic_Variant_A"],PARAMETER["False_Easting",2000000.0],PARAMETER["False_Northing",2000000.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Scale_Factor",0.994],PARAMETER["Latitude_Of_Origin",-90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        32661,
        r#"PROJCS["UPS_North",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic"],PARAMETER["False_Easting",2000000.0],PARAMETER["False_Northing",2000000.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Scale_Factor",0.994],PARAMETER["Latitude_Of_Origin",90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        32761,
        r#"PROJCS["UPS_South",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Stereographic"],PARAMETER["False_Easting",2000000.0],PARAMETER["False_Northing",2000000.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Scale_Factor",0.994],PARAMETER["Latitude_Of_Origin",-90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3571,
        r#"PROJCS["WGS_1984_North_Pole_LAEA_Bering_Sea",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",180.0],PARAMETER["Latitude_Of_Origin",90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3573,
        r#"PROJCS["WGS_1984_North_Pole_LAEA_Canada",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-100.0],PARAMETER["Latitude_Of_Origin",90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        6931,
        r#"PROJCS["WGS_1984_EASE-Grid_2.0_North",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Latitude_Of_Origin",90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        6932,
        r#"PROJCS["WGS_1984_EASE-Grid_2.0_South",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",0.0],PARAMETER["Latitude_Of_Origin",-90.0],UNIT["Meter",1.0]]"#,
    ),
    (
        2154,
        r#"PROJCS["RGF_1993_Lambert_93",GEOGCS["GCS_RGF_1993",DATUM["D_RGF_1993",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic"],PARAMETER["False_Easting",700000.0],PARAMETER["False_Northing",6600000.0],PARAMETER["Central_Meridian",3.0],PARAMETER["Standard_Parallel_1",49.0],PARAMETER["Standard_Parallel_2",44.0],PARAMETER["Latitude_Of_Origin",46.5],UNIT["Meter",1.0]]"#,
    ),
    (
        3034,
        r#"PROJCS["ETRS_1989_LCC",GEOGCS["GCS_ETRS_1989",DATUM["D_ETRS_1989",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic"],PARAMETER["False_Easting",4000000.0],PARAMETER["False_Northing",2800000.0],PARAMETER["Central_Meridian",10.0],PARAMETER["Standard_Parallel_1",35.0],PARAMETER["Standard_Parallel_2",65.0],PARAMETER["Latitude_Of_Origin",52.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3035,
        r#"PROJCS["ETRS_1989_LAEA",GEOGCS["GCS_ETRS_1989",DATUM["D_ETRS_1989",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",4321000.0],PARAMETER["False_Northing",3210000.0],PARAMETER["Central_Meridian",10.0],PARAMETER["Latitude_Of_Origin",52.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3006,
        r#"PROJCS["SWEREF99_TM",GEOGCS["GCS_SWEREF99",DATUM["D_SWEREF99",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["False_Easting",500000.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",15.0],PARAMETER["Scale_Factor",0.9996],PARAMETER["Latitude_Of_Origin",0.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3067,
        r#"PROJCS["EUREF_FIN_TM35FIN",GEOGCS["GCS_ETRS_1989",DATUM["D_ETRS_1989",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["False_Easting",500000.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",27.0],PARAMETER["Scale_Factor",0.9996],PARAMETER["Latitude_Of_Origin",0.0],UNIT["Meter",1.0]]"#,
    ),
    (
        5070,
        r#"PROJCS["NAD_1983_Contiguous_USA_Albers",GEOGCS["GCS_North_American_1983",DATUM["D_North_American_1983",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Albers"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-96.0],PARAMETER["Standard_Parallel_1",29.5],PARAMETER["Standard_Parallel_2",45.5],PARAMETER["Latitude_Of_Origin",23.0],UNIT["Meter",1.0]]"#,
    ),
    (
        3338,
        r#"PROJCS["NAD_1983_Alaska_Albers",GEOGCS["GCS_North_American_1983",DATUM["D_North_American_1983",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Albers"],PARAMETER["False_Easting",0.0],PARAMETER["False_Northing",0.0],PARAMETER["Central_Meridian",-154.0],PARAMETER["Standard_Parallel_1",55.0],PARAMETER["Standard_Parallel_2",65.0],PARAMETER["Latitude_Of_Origin",50.0],UNIT["Meter",1.0]]"#,
    ),
];
