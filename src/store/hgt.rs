//! SRTM's HGT tiles as ingest sources: `N39E040.hgt`, and zipped as they are
//! delivered (`N39E040.SRTMGL1.hgt.zip`, `NASADEM_HGT_n39e040.zip`).
//!
//! An HGT file is a square degree of big-endian 16-bit heights in metres,
//! rows north to south, -32768 where there is no data, with no header: the
//! name places it and the size gives the spacing. Its pixels are points: the
//! tile N39E040 has its south-west sample at exactly 39 N 40 E and its
//! north-east one at 40 N 41 E, so the rows and columns overlap the
//! neighbouring tiles by one. The georeferencing is the one GDAL's SRTMHGT
//! driver gives (checked against GDAL 3.10.3): WGS 84 longitude and latitude,
//! pixels as areas centred on the samples, sizes 1201 x 1201 (3"), 3601 x 3601
//! (1"), 1801 x 3601 (2" x 1", above 50 degrees in some products) and 7201 x
//! 7201 (0.5"). Heights are SRTM's, above the EGM96 geoid; they are not
//! changed. Ingest then puts the tile into a UTM zone like any DSM in degrees.
//!
//! A plain tile is read a band of rows at a time from the file; a zipped one
//! is inflated as its rows are read (`zip`), so neither is held whole.

use std::os::unix::fs::FileExt;
use std::path::Path;

use super::source::{RowSource, SourceError, SourceRaster};
use crate::geo::GeoTransform;
use crate::geotiff::geokeys::{crs_from_entries, key, GeoKeyValue};

mod zip;

/// The no-data value of HGT files (SRTM's voids).
pub const VOID: i16 = -32768;

/// The (columns, rows) an HGT file may have, with their spacing's name.
const SIZES: [(u64, u64, &str); 4] = [
    (1201, 1201, "3\""),
    (3601, 3601, "1\""),
    (1801, 3601, "2\" x 1\""),
    (7201, 7201, "0.5\""),
];

/// A one-degree tile by its south-west sample (whole degrees).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    pub lat: i32,
    pub lon: i32,
}

impl Tile {
    /// The tile a file name starts with (`N39E040`, `s12w077`, either case),
    /// followed by the end of the name or a dot, as GDAL reads them.
    pub fn of_name(name: &str) -> Option<Tile> {
        let b = name.as_bytes();
        if b.len() < 7 || b.get(7).is_some_and(|&c| c != b'.') {
            return None;
        }
        let digits = |r: std::ops::Range<usize>| -> Option<i32> {
            let s = name.get(r)?;
            s.bytes()
                .all(|c| c.is_ascii_digit())
                .then(|| s.parse().ok())?
        };
        let lat_sign = match b[0].to_ascii_uppercase() {
            b'N' => 1,
            b'S' => -1,
            _ => return None,
        };
        let lon_sign = match b[3].to_ascii_uppercase() {
            b'E' => 1,
            b'W' => -1,
            _ => return None,
        };
        let tile = Tile {
            lat: lat_sign * digits(1..3)?,
            lon: lon_sign * digits(4..7)?,
        };
        ((-90..=89).contains(&tile.lat) && (-180..=180).contains(&tile.lon)).then_some(tile)
    }

    /// The name GDAL and the SRTM products give it: `N39E040`, `S12W077`.
    pub fn name(&self) -> String {
        let (ns, ew) = (
            if self.lat < 0 { 'S' } else { 'N' },
            if self.lon < 0 { 'W' } else { 'E' },
        );
        format!("{ns}{:02}{ew}{:03}", self.lat.abs(), self.lon.abs())
    }

    /// The transform of a tile of `cols` x `rows` samples: pixels centred on
    /// the samples, which run from the south-west corner to the north-east.
    pub fn geotransform(&self, cols: u64, rows: u64) -> GeoTransform {
        let (dx, dy) = (1.0 / (cols - 1) as f64, 1.0 / (rows - 1) as f64);
        let west = f64::from(self.lon) - 0.5 * dx;
        let north = f64::from(self.lat) + 1.0 + 0.5 * dy;
        GeoTransform::north_up(west, north, dx, dy)
    }
}

/// Whether `path` is read as an HGT tile: `*.hgt`, `*.hgt.zip`, or any
/// other `*.zip` (which must then hold one).
pub fn is_hgt_path(path: &Path) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    name.ends_with(".hgt") || name.ends_with(".zip")
}

/// The DSM id of a zip archive named `name`: the name without `.zip`, then
/// without `.hgt` (`N39E040.SRTMGL1.hgt.zip` gives `N39E040.SRTMGL1`,
/// `NASADEM_HGT_n39e040.zip` gives `NASADEM_HGT_n39e040`).
pub fn id_of_zip(name: &str) -> String {
    let strip = |s: &str, tail: &str| {
        let cut = s.len().saturating_sub(tail.len());
        match s.get(cut..) {
            Some(end) if end.eq_ignore_ascii_case(tail) => s[..cut].to_string(),
            _ => s.to_string(),
        }
    };
    strip(&strip(name, ".zip"), ".hgt")
}

/// Where the heights are: the file (read a band of rows at a time) or the
/// member of a zip archive, inflated as it is read.
enum Heights {
    File(std::fs::File),
    Zip(Box<ZipRows>),
}

/// The rows of a zipped tile, streamed: the member is inflated front to back
/// and the rows of the last request are held, so the overlapping, rising
/// bands ingest asks for are inflated once. A request before the held rows
/// starts the stream again.
struct ZipRows {
    member: zip::Member,
    /// Opened at the first read (ingest opens every input to read its header).
    stream: Option<zip::MemberReader<std::fs::File>>,
    /// Rows `held_row0 .. next_row`, as stored.
    held: Vec<u8>,
    held_row0: u64,
    /// The row the stream yields next.
    next_row: u64,
}

impl ZipRows {
    /// Rows `row0 .. row0 + rows` of `row_bytes` each, as stored.
    fn rows(
        &mut self,
        path: &Path,
        row0: u64,
        rows: u64,
        row_bytes: u64,
    ) -> Result<&[u8], SourceError> {
        if row0 < self.held_row0 {
            (self.stream, self.next_row, self.held_row0) = (None, 0, 0);
            self.held.clear();
        }
        let drop = row0.min(self.next_row) - self.held_row0;
        self.held.drain(..(drop * row_bytes) as usize);
        self.held_row0 += drop;
        let stream = match &mut self.stream {
            Some(s) => s,
            None => {
                let file = std::fs::File::open(path).map_err(|e| io(path, e))?;
                let s = zip::open_member(file, &self.member).map_err(|e| bad(path, e))?;
                self.stream.insert(s)
            }
        };
        // rows before the request: inflated and let go, 64 at a time
        let mut scratch = Vec::new();
        while self.next_row < row0 {
            let n = (row0 - self.next_row).min(64);
            scratch.resize((n * row_bytes) as usize, 0);
            stream.read_exact(&mut scratch).map_err(|e| bad(path, e))?;
            self.next_row += n;
            self.held_row0 = self.next_row;
        }
        if self.next_row < row0 + rows {
            let at = self.held.len();
            self.held
                .resize(at + ((row0 + rows - self.next_row) * row_bytes) as usize, 0);
            stream
                .read_exact(&mut self.held[at..])
                .map_err(|e| bad(path, e))?;
            self.next_row = row0 + rows;
        }
        let start = ((row0 - self.held_row0) * row_bytes) as usize;
        Ok(&self.held[start..start + (rows * row_bytes) as usize])
    }
}

/// An HGT tile, plain or zipped.
pub struct HgtSource {
    raster: SourceRaster,
    heights: Heights,
}

fn bad(path: &Path, what: impl std::fmt::Display) -> SourceError {
    SourceError {
        message: format!("{}: {what}", path.display()),
        bad_input: true,
    }
}

fn io(path: &Path, e: std::io::Error) -> SourceError {
    SourceError {
        message: format!("{}: {e}", path.display()),
        bad_input: false,
    }
}

/// The (columns, rows) of an HGT file of `bytes`.
fn size_of(path: &Path, bytes: u64) -> Result<(u64, u64), SourceError> {
    SIZES
        .iter()
        .find(|(c, r, _)| c * r * 2 == bytes)
        .map(|&(c, r, _)| (c, r))
        .ok_or_else(|| {
            let sizes: Vec<String> = SIZES
                .iter()
                .map(|(c, r, s)| format!("{c} x {r} ({s})"))
                .collect();
            bad(
                path,
                format!(
                    "{bytes} bytes is not an SRTM HGT tile (truncated?): a tile is {} samples of 2 bytes",
                    sizes.join(", ")
                ),
            )
        })
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

impl HgtSource {
    pub fn open(path: &Path) -> Result<HgtSource, SourceError> {
        let name = file_name(path);
        let (tile, heights, bytes) = if name.to_ascii_lowercase().ends_with(".zip") {
            let mut archive = std::fs::File::open(path).map_err(|e| io(path, e))?;
            let (tile, member) = Self::member(path, &name, &mut archive)?;
            let len = member.uncompressed;
            let rows = ZipRows {
                member,
                stream: None,
                held: Vec::new(),
                held_row0: 0,
                next_row: 0,
            };
            (tile, Heights::Zip(Box::new(rows)), len)
        } else {
            let tile = Tile::of_name(&name).ok_or_else(|| {
                bad(
                    path,
                    "an HGT file's name must start with its tile, as N39E040.hgt (the name places it)",
                )
            })?;
            let file = std::fs::File::open(path).map_err(|e| io(path, e))?;
            let len = file.metadata().map_err(|e| io(path, e))?.len();
            (tile, Heights::File(file), len)
        };
        let (cols, rows) = size_of(path, bytes)?;
        let crs = crs_from_entries(vec![
            (key::GT_MODEL_TYPE, GeoKeyValue::Short(2)),
            (key::GT_RASTER_TYPE, GeoKeyValue::Short(1)),
            (key::GEOGRAPHIC_TYPE, GeoKeyValue::Short(4326)),
        ])
        .map_err(|e| bad(path, e))?;
        let raster = SourceRaster {
            path: path.to_path_buf(),
            width: cols,
            height: rows,
            geotransform: tile.geotransform(cols, rows),
            crs,
            nodata: Some(f64::from(VOID)),
            dtype: "Int16".into(),
            height_unit: Some("m".into()),
            georeferenced_by: Vec::new(),
        };
        Ok(HgtSource { raster, heights })
    }

    /// The tile and the one `.hgt` member of a zip archive, from its central
    /// directory; a tile the archive's own name gives must be the same.
    fn member(
        path: &Path,
        name: &str,
        archive: &mut std::fs::File,
    ) -> Result<(Tile, zip::Member), SourceError> {
        let members = zip::members(archive).map_err(|e| bad(path, e))?;
        let hgt: Vec<&zip::Member> = (members.iter())
            .filter(|m| m.name.to_ascii_lowercase().ends_with(".hgt"))
            .collect();
        let [member] = hgt.as_slice() else {
            let names: Vec<&str> = members.iter().map(|m| m.name.as_str()).take(5).collect();
            return Err(bad(
                path,
                format!(
                    "a .zip input must hold one SRTM .hgt tile; this one holds {} ({}{})",
                    if hgt.is_empty() { "none" } else { "several" },
                    names.join(", "),
                    if members.len() > 5 { ", ..." } else { "" }
                ),
            ));
        };
        let inner = member.name.rsplit('/').next().unwrap_or(&member.name);
        let tile = Tile::of_name(inner).ok_or_else(|| {
            bad(
                path,
                format!(
                    "its member {} is not named by its tile, as N39E040.hgt",
                    member.name
                ),
            )
        })?;
        if let Some(outer) = Tile::of_name(name) {
            if outer != tile {
                return Err(bad(
                    path,
                    format!(
                        "the archive's name says {} but it holds {}",
                        outer.name(),
                        member.name
                    ),
                ));
            }
        }
        Ok((tile, (*member).clone()))
    }
}

/// Big-endian 16-bit heights to f32, [`VOID`] to NaN.
fn decode(bytes: &[u8], out: &mut Vec<f32>) {
    out.clear();
    out.extend(
        bytes
            .chunks_exact(2)
            .map(|b| match i16::from_be_bytes([b[0], b[1]]) {
                VOID => f32::NAN,
                h => f32::from(h),
            }),
    );
}

impl RowSource for HgtSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        let mut out = Vec::new();
        self.read_rows_into(row0, rows, &mut out)?;
        Ok(out)
    }

    fn read_rows_into(
        &mut self,
        row0: u64,
        rows: u64,
        out: &mut Vec<f32>,
    ) -> Result<(), SourceError> {
        let path = &self.raster.path;
        if row0 + rows > self.raster.height {
            return Err(SourceError {
                message: format!(
                    "{}: rows {row0}..{} past the height {}",
                    path.display(),
                    row0 + rows,
                    self.raster.height
                ),
                bad_input: false,
            });
        }
        let row_bytes = self.raster.width * 2;
        match &mut self.heights {
            Heights::Zip(zipped) => decode(zipped.rows(path, row0, rows, row_bytes)?, out),
            Heights::File(file) => {
                let mut buf = vec![0u8; (rows * row_bytes) as usize];
                file.read_exact_at(&mut buf, row0 * row_bytes)
                    .map_err(|e| io(path, e))?;
                decode(&buf, out);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
