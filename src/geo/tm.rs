//! Transverse Mercator on an ellipsoid, and the UTM zones built on it: what
//! ingest needs to put a DSM delivered in longitude and latitude (SRTM,
//! Copernicus, ALOS) into metres.
//!
//! Krüger's series to sixth order in the third flattening n, as in Karney,
//! "Transverse Mercator with an accuracy of a few nanometres" (J. Geodesy
//! 85, 2011), eqs. 7-11 and 35-36: within 4,000 km of the central meridian it
//! is exact to a few nanometres, far more than a UTM zone needs. The inverse
//! finds the latitude from the conformal one by Newton's method (Karney's
//! eqs. 19-21), converging in two or three steps. The unit tests hold both
//! directions to GDAL/PROJ's answers.

/// An ellipsoid by its semi-major axis (m) and flattening.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    pub a: f64,
    pub f: f64,
}

impl Ellipsoid {
    pub const WGS84: Ellipsoid = Ellipsoid {
        a: 6_378_137.0,
        f: 1.0 / 298.257_223_563,
    };
    /// GRS 1980 (NAD83, ETRS89).
    pub const GRS80: Ellipsoid = Ellipsoid {
        a: 6_378_137.0,
        f: 1.0 / 298.257_222_101,
    };

    fn e2(&self) -> f64 {
        self.f * (2.0 - self.f)
    }

    /// The length (m) of one degree of longitude and of latitude at `lat_deg`:
    /// the prime vertical's N cos(phi) and the meridian's M, times pi / 180.
    pub fn metres_per_degree(&self, lat_deg: f64) -> (f64, f64) {
        let phi = lat_deg.to_radians();
        let w2 = 1.0 - self.e2() * phi.sin().powi(2);
        let n = self.a / w2.sqrt();
        let m = self.a * (1.0 - self.e2()) / w2.powf(1.5);
        let per_rad = std::f64::consts::PI / 180.0;
        (n * phi.cos() * per_rad, m * per_rad)
    }
}

/// A Transverse Mercator projection: ellipsoid, central meridian (degrees),
/// scale on it, false easting and northing (m); latitude of origin 0.
#[derive(Clone, Debug)]
pub struct TransverseMercator {
    e: f64,
    lon0: f64,
    k0: f64,
    false_easting: f64,
    false_northing: f64,
    /// The rectifying radius A of Karney's eq. 14.
    radius: f64,
    alpha: [f64; 6],
    beta: [f64; 6],
}

impl TransverseMercator {
    pub fn new(
        ellipsoid: Ellipsoid,
        lon0_deg: f64,
        k0: f64,
        false_easting: f64,
        false_northing: f64,
    ) -> TransverseMercator {
        let n = ellipsoid.f / (2.0 - ellipsoid.f);
        let (n2, n3) = (n * n, n * n * n);
        let (n4, n5, n6) = (n3 * n, n3 * n2, n3 * n3);
        let radius = ellipsoid.a / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0 + n6 / 256.0);
        let alpha = [
            n / 2.0 - 2.0 * n2 / 3.0 + 5.0 * n3 / 16.0 + 41.0 * n4 / 180.0 - 127.0 * n5 / 288.0
                + 7891.0 * n6 / 37800.0,
            13.0 * n2 / 48.0 - 3.0 * n3 / 5.0 + 557.0 * n4 / 1440.0 + 281.0 * n5 / 630.0
                - 1_983_433.0 * n6 / 1_935_360.0,
            61.0 * n3 / 240.0 - 103.0 * n4 / 140.0
                + 15061.0 * n5 / 26880.0
                + 167_603.0 * n6 / 181_440.0,
            49561.0 * n4 / 161_280.0 - 179.0 * n5 / 168.0 + 6_601_661.0 * n6 / 7_257_600.0,
            34729.0 * n5 / 80640.0 - 3_418_889.0 * n6 / 1_995_840.0,
            212_378_941.0 * n6 / 319_334_400.0,
        ];
        let beta = [
            n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0 - n4 / 360.0 - 81.0 * n5 / 512.0
                + 96199.0 * n6 / 604_800.0,
            n2 / 48.0 + n3 / 15.0 - 437.0 * n4 / 1440.0 + 46.0 * n5 / 105.0
                - 1_118_711.0 * n6 / 3_870_720.0,
            17.0 * n3 / 480.0 - 37.0 * n4 / 840.0 - 209.0 * n5 / 4480.0 + 5569.0 * n6 / 90720.0,
            4397.0 * n4 / 161_280.0 - 11.0 * n5 / 504.0 - 830_251.0 * n6 / 7_257_600.0,
            4583.0 * n5 / 161_280.0 - 108_847.0 * n6 / 3_991_680.0,
            20_648_693.0 * n6 / 638_668_800.0,
        ];
        TransverseMercator {
            e: ellipsoid.e2().sqrt(),
            lon0: lon0_deg,
            k0,
            false_easting,
            false_northing,
            radius,
            alpha,
            beta,
        }
    }

    /// (easting, northing) in metres of (longitude, latitude) in degrees.
    pub fn forward(&self, lon_deg: f64, lat_deg: f64) -> (f64, f64) {
        let lambda = (lon_deg - self.lon0).to_radians();
        let phi = lat_deg.to_radians();
        let s = phi.sin();
        // tan of the conformal latitude
        let t = (s.atanh() - self.e * (self.e * s).atanh()).sinh();
        let xi1 = t.atan2(lambda.cos());
        let eta1 = (lambda.sin() / t.hypot(1.0)).atanh();
        let (mut xi, mut eta) = (xi1, eta1);
        for (j, a) in self.alpha.iter().enumerate() {
            let k = 2.0 * (j + 1) as f64;
            xi += a * (k * xi1).sin() * (k * eta1).cosh();
            eta += a * (k * xi1).cos() * (k * eta1).sinh();
        }
        let scale = self.k0 * self.radius;
        (
            self.false_easting + scale * eta,
            self.false_northing + scale * xi,
        )
    }

    /// (longitude, latitude) in degrees of (easting, northing) in metres.
    pub fn inverse(&self, easting: f64, northing: f64) -> (f64, f64) {
        let scale = self.k0 * self.radius;
        let xi = (northing - self.false_northing) / scale;
        let eta = (easting - self.false_easting) / scale;
        let (mut xi1, mut eta1) = (xi, eta);
        for (j, b) in self.beta.iter().enumerate() {
            let k = 2.0 * (j + 1) as f64;
            xi1 -= b * (k * xi).sin() * (k * eta).cosh();
            eta1 -= b * (k * xi).cos() * (k * eta).sinh();
        }
        let tau1 = xi1.sin() / eta1.sinh().hypot(xi1.cos());
        let lambda = eta1.sinh().atan2(xi1.cos());
        let tau = self.tau_of_conformal(tau1);
        (self.lon0 + lambda.to_degrees(), tau.atan().to_degrees())
    }

    /// tan(latitude) from tan(conformal latitude), Newton's method.
    fn tau_of_conformal(&self, tau1: f64) -> f64 {
        let (e, e2m) = (self.e, 1.0 - self.e * self.e);
        let mut tau = tau1;
        for _ in 0..8 {
            let hyp = tau.hypot(1.0);
            let sigma = (e * (e * tau / hyp).atanh()).sinh();
            let tau1_i = tau * sigma.hypot(1.0) - sigma * hyp;
            let step = (tau1 - tau1_i) / tau1_i.hypot(1.0) * (1.0 + e2m * tau * tau) / (e2m * hyp);
            tau += step;
            if step.abs() <= 1e-14 * tau.abs().max(1.0) {
                break;
            }
        }
        tau
    }
}

/// The geodetic datum of a geographic CRS whose UTM zones have EPSG codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Datum {
    Wgs84,
    Nad83,
    Etrs89,
}

impl Datum {
    pub fn ellipsoid(self) -> Ellipsoid {
        match self {
            Datum::Wgs84 => Ellipsoid::WGS84,
            Datum::Nad83 | Datum::Etrs89 => Ellipsoid::GRS80,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Datum::Wgs84 => "WGS 84",
            Datum::Nad83 => "NAD83",
            Datum::Etrs89 => "ETRS89",
        }
    }
}

/// A UTM zone on one datum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Utm {
    pub datum: Datum,
    /// 1 to 60.
    pub zone: u8,
    pub north: bool,
}

impl Utm {
    /// The zone holding `lon_deg` (the plain 6-degree zones, without the
    /// Norway and Svalbard exceptions), in the hemisphere of `lat_deg`.
    pub fn containing(datum: Datum, lon_deg: f64, lat_deg: f64) -> Utm {
        let lon = (lon_deg + 180.0).rem_euclid(360.0);
        let zone = ((lon / 6.0).floor() as u8).min(59) + 1;
        Utm {
            datum,
            zone,
            north: lat_deg >= 0.0,
        }
    }

    /// The EPSG code of the projected CRS, when EPSG defines this zone:
    /// WGS 84 326zz / 327zz, NAD83 269zz (zones 1-23, north), ETRS89 258zz
    /// (zones 28-38, north).
    pub fn epsg(&self) -> Option<u32> {
        let zone = u32::from(self.zone);
        match (self.datum, self.north) {
            (Datum::Wgs84, true) => Some(32600 + zone),
            (Datum::Wgs84, false) => Some(32700 + zone),
            (Datum::Nad83, true) if (1..=23).contains(&zone) => Some(26900 + zone),
            (Datum::Etrs89, true) if (28..=38).contains(&zone) => Some(25800 + zone),
            _ => None,
        }
    }

    /// The zone an EPSG code names (the inverse of [`Utm::epsg`]).
    pub fn from_epsg(code: u32) -> Option<Utm> {
        let (datum, north, zone) = match code {
            32601..=32660 => (Datum::Wgs84, true, code - 32600),
            32701..=32760 => (Datum::Wgs84, false, code - 32700),
            26901..=26923 => (Datum::Nad83, true, code - 26900),
            25828..=25838 => (Datum::Etrs89, true, code - 25800),
            _ => return None,
        };
        Some(Utm {
            datum,
            zone: zone as u8,
            north,
        })
    }

    /// "UTM 37N (WGS 84)".
    pub fn label(&self) -> String {
        let hemisphere = if self.north { 'N' } else { 'S' };
        format!("UTM {}{hemisphere} ({})", self.zone, self.datum.name())
    }

    pub fn projection(&self) -> TransverseMercator {
        let lon0 = -183.0 + 6.0 * f64::from(self.zone);
        let false_northing = if self.north { 0.0 } else { 10_000_000.0 };
        TransverseMercator::new(
            self.datum.ellipsoid(),
            lon0,
            0.9996,
            500_000.0,
            false_northing,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (EPSG code, longitude, latitude, easting, northing): GDAL 3.10.3 / PROJ
    /// (`rasterio.warp.transform`), random points up to 4.5 degrees from the
    /// central meridian and 83 degrees from the equator, four datums and
    /// zones, both hemispheres, zone 1 across the antimeridian.
    const GDAL: [(u32, f64, f64, f64, f64); 30] = [
        (
            32637,
            39.000000000000,
            45.000000000000,
            500000.000000,
            4982950.400227,
        ),
        (
            32637,
            42.817895256214,
            38.916130783231,
            831040.281675,
            4314403.787741,
        ),
        (
            32637,
            39.070571457560,
            48.959248380116,
            505165.984223,
            5422928.032713,
        ),
        (
            32637,
            36.161943094694,
            42.732462720949,
            267665.895129,
            4735012.234787,
        ),
        (
            32637,
            40.168944481951,
            65.920591982896,
            553216.830156,
            7311554.694115,
        ),
        (
            32637,
            35.347111106063,
            25.530604166523,
            132829.430756,
            2828751.993599,
        ),
        (
            32733,
            15.000000000000,
            -45.000000000000,
            500000.000000,
            5017049.599773,
        ),
        (
            32733,
            16.740946342871,
            -3.955127750512,
            693295.101846,
            9562629.977190,
        ),
        (
            32733,
            19.339740787189,
            -80.092516942859,
            583283.688367,
            1104979.245463,
        ),
        (
            32733,
            16.385302801805,
            -51.283923127732,
            596609.639873,
            4317689.662770,
        ),
        (
            32733,
            11.917446856261,
            -1.737560798342,
            156979.345774,
            9807666.740044,
        ),
        (
            32733,
            15.255431395534,
            -5.412966176431,
            528297.305789,
            9401680.805765,
        ),
        (
            26917,
            -81.000000000000,
            45.000000000000,
            500000.000000,
            4982950.400107,
        ),
        (
            26917,
            -85.229256696977,
            38.774593050921,
            132549.591006,
            4300265.084186,
        ),
        (
            26917,
            -81.535219950090,
            70.000238102779,
            479570.437225,
            7765989.354239,
        ),
        (
            26917,
            -80.827882967123,
            53.324065903332,
            511464.159862,
            5908334.984959,
        ),
        (
            26917,
            -81.002041630139,
            55.152086380955,
            499869.894378,
            6111715.656049,
        ),
        (
            26917,
            -81.384031065604,
            23.448439222271,
            460774.917481,
            2593215.577456,
        ),
        (
            25832,
            9.000000000000,
            45.000000000000,
            500000.000000,
            4982950.400107,
        ),
        (
            25832,
            12.061939945436,
            58.894293773581,
            676415.247447,
            6532319.255783,
        ),
        (
            25832,
            7.337494953140,
            19.447436882652,
            325475.330938,
            2151179.741727,
        ),
        (
            25832,
            7.101359525828,
            6.293438713694,
            289955.853106,
            696023.700653,
        ),
        (
            25832,
            11.396590977694,
            33.532983905776,
            722549.277353,
            3712948.220095,
        ),
        (
            25832,
            12.119252596931,
            32.387366365740,
            793446.887418,
            3587654.830945,
        ),
        (
            32601,
            -177.000000000000,
            45.000000000000,
            500000.000000,
            4982950.400227,
        ),
        (
            32601,
            -181.495095566500,
            17.801686715193,
            23207.869675,
            1973971.532258,
        ),
        (
            32601,
            -173.307552647062,
            39.273950271127,
            818543.073827,
            4353680.448979,
        ),
        (
            32601,
            -172.676769529431,
            33.287512016541,
            902696.198966,
            3691509.217836,
        ),
        (
            32601,
            -180.842654905497,
            52.430030259307,
            238785.062881,
            5815816.533644,
        ),
        (
            32601,
            -174.493402271910,
            22.756485915137,
            757396.378463,
            2518742.089363,
        ),
    ];

    #[test]
    fn utm_matches_gdal_both_ways_to_a_millimetre() {
        for (code, lon, lat, e, n) in GDAL {
            let tm = Utm::from_epsg(code).unwrap().projection();
            let (x, y) = tm.forward(lon, lat);
            assert!(
                (x - e).abs() < 1e-3 && (y - n).abs() < 1e-3,
                "EPSG:{code} ({lon}, {lat}): ({x:.6}, {y:.6}) against GDAL ({e}, {n})"
            );
            let (lo, la) = tm.inverse(e, n);
            // 1e-8 degrees is about a millimetre
            let dlon = (lo - lon + 540.0).rem_euclid(360.0) - 180.0;
            assert!(
                dlon.abs() < 1e-8 && (la - lat).abs() < 1e-8,
                "EPSG:{code} ({e}, {n}): ({lo:.12}, {la:.12}) against ({lon}, {lat})"
            );
        }
    }

    #[test]
    fn forward_then_inverse_is_the_identity_over_a_zone() {
        let tm = Utm::from_epsg(32633).unwrap().projection();
        for i in 0..=40 {
            for j in 0..=40 {
                let lon = 15.0 - 5.0 + 10.0 * f64::from(i) / 40.0;
                let lat = -80.0 + 164.0 * f64::from(j) / 40.0;
                let (e, n) = tm.forward(lon, lat);
                let (lo, la) = tm.inverse(e, n);
                assert!(
                    (lo - lon).abs() < 1e-11 && (la - lat).abs() < 1e-11,
                    "({lon}, {lat}) -> ({lo}, {la})"
                );
            }
        }
    }

    #[test]
    fn zones_and_codes() {
        let z = Utm::containing(Datum::Wgs84, 40.42, 39.58);
        assert_eq!((z.zone, z.north, z.epsg()), (37, true, Some(32637)));
        assert_eq!(
            Utm::containing(Datum::Wgs84, -180.0, -1.0).epsg(),
            Some(32701)
        );
        assert_eq!(Utm::containing(Datum::Wgs84, 180.0, 1.0).zone, 1);
        assert_eq!(Utm::containing(Datum::Wgs84, 179.99, 1.0).zone, 60);
        assert_eq!(
            Utm::containing(Datum::Nad83, -100.0, 40.0).epsg(),
            Some(26914)
        );
        assert_eq!(Utm::containing(Datum::Etrs89, -30.0, 40.0).epsg(), None);
        assert_eq!(Utm::containing(Datum::Nad83, -100.0, -40.0).epsg(), None);
        for code in [32601, 32660, 32701, 32760, 26901, 26923, 25828, 25838] {
            assert_eq!(Utm::from_epsg(code).unwrap().epsg(), Some(code));
        }
        assert_eq!(Utm::from_epsg(2154), None);
        assert_eq!(Utm::from_epsg(32637).unwrap().label(), "UTM 37N (WGS 84)");
        // one degree of latitude is 110.6 km at the equator, 111.7 km at the pole
        let (_, m0) = Ellipsoid::WGS84.metres_per_degree(0.0);
        let (p60, m90) = Ellipsoid::WGS84.metres_per_degree(90.0);
        assert!((m0 - 110_574.3).abs() < 1.0 && (m90 - 111_694.0).abs() < 1.0);
        assert!(p60.abs() < 1e-6);
    }
}
