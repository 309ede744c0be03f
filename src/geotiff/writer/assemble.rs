//! The second half of the COG writer, run by `finish()`: overview levels built
//! from tiles read back from the spill file, the layout of the final file (all
//! IFDs first, then tile data from the smallest overview to full resolution,
//! row-major within a level) and the copy of the spilled tiles into it.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::Path;

use rayon::prelude::*;

use super::{ifd, tile, CogOptions};

/// GDAL's COG block framing: each tile is preceded by its size (u32, the
/// BLOCK_LEADER) and followed by a copy of its last 4 bytes (the BLOCK_TRAILER).
const TILE_FRAME_BYTES: u64 = 8;

/// Where one compressed tile sits in the spill file.
#[derive(Clone, Copy, Debug)]
pub(super) struct SpillRef {
    pub offset: u64,
    pub len: u64,
}

/// One resolution level: where its tiles sit in the spill file (row-major index).
pub(super) struct Level {
    pub width: u64,
    pub height: u64,
    pub tiles_x: u64,
    pub tiles_y: u64,
    pub refs: Vec<SpillRef>,
}

impl Level {
    /// Bytes of the level's tile data in the COG, leaders and trailers included.
    fn data_bytes(&self) -> u64 {
        self.refs.iter().map(|r| r.len + TILE_FRAME_BYTES).sum()
    }
}

/// The 2x overview of `prev`, appended to the spill file one tile row at a time
/// (the tiles of a row are built in parallel, then appended in order).
pub(super) fn build_overview(
    spill: &File,
    prev: &Level,
    spill_len: &mut u64,
    options: &CogOptions,
) -> std::io::Result<Level> {
    let t = options.tile_size as u64;
    let (width, height) = (prev.width.div_ceil(2), prev.height.div_ceil(2));
    let (tiles_x, tiles_y) = (width.div_ceil(t), height.div_ceil(t));
    let mut refs = Vec::with_capacity((tiles_x * tiles_y) as usize);
    let read_child = |cx: u64, cy: u64| -> std::io::Result<Option<Vec<f32>>> {
        if cx >= prev.tiles_x || cy >= prev.tiles_y {
            return Ok(None);
        }
        let r = prev.refs[(cy * prev.tiles_x + cx) as usize];
        let mut buf = vec![0u8; r.len as usize];
        spill.read_exact_at(&mut buf, r.offset)?;
        tile::decode_tile(&buf, t as usize, options).map(Some)
    };
    for ty in 0..tiles_y {
        let row: Vec<Vec<u8>> = (0..tiles_x)
            .into_par_iter()
            .map(|tx| {
                let mut children: [Option<Vec<f32>>; 4] = Default::default();
                for (q, child) in children.iter_mut().enumerate() {
                    *child = read_child(2 * tx + (q as u64 % 2), 2 * ty + (q as u64 / 2))?;
                }
                let quads = [0, 1, 2, 3].map(|q| children[q].as_deref());
                let values = tile::downsample_2x(quads, t as usize);
                let valid = tile::Valid {
                    width: (width - tx * t).min(t) as usize,
                    height: (height - ty * t).min(t) as usize,
                };
                tile::encode_tile(&values, t as usize, valid, options)
            })
            .collect::<std::io::Result<_>>()?;
        for bytes in row {
            spill.write_all_at(&bytes, *spill_len)?;
            refs.push(SpillRef {
                offset: *spill_len,
                len: bytes.len() as u64,
            });
            *spill_len += bytes.len() as u64;
        }
    }
    Ok(Level {
        width,
        height,
        tiles_x,
        tiles_y,
        refs,
    })
}

/// File offsets of every IFD and of each level's tile data.
struct Layout {
    bigtiff: bool,
    ifd_at: Vec<u64>,
    data_at: Vec<u64>,
    total_bytes: u64,
}

fn plan_layout(levels: &[Level], options: &CogOptions, bigtiff: bool) -> Layout {
    let mut pos = ifd::header_len(bigtiff);
    let mut ifd_at = Vec::with_capacity(levels.len());
    for (i, level) in levels.iter().enumerate() {
        ifd_at.push(pos);
        let zeros = vec![0u64; level.refs.len()];
        let entries = ifd::image_entries(&image_tags(levels, i, options, &zeros, &zeros), bigtiff);
        pos += ifd::serialize_ifd(&entries, pos, 0, bigtiff).len() as u64;
    }
    let mut data_at = vec![0u64; levels.len()];
    for (i, level) in levels.iter().enumerate().rev() {
        data_at[i] = pos;
        pos += level.data_bytes();
    }
    Layout {
        bigtiff,
        ifd_at,
        data_at,
        total_bytes: pos,
    }
}

fn image_tags<'a>(
    levels: &[Level],
    i: usize,
    options: &'a CogOptions,
    offsets: &'a [u64],
    counts: &'a [u64],
) -> ifd::ImageTags<'a> {
    ifd::ImageTags {
        width: levels[i].width,
        height: levels[i].height,
        tile_size: options.tile_size,
        overview: i > 0,
        tile_offsets: offsets,
        tile_byte_counts: counts,
        geo: (i == 0).then_some((&options.geotransform, &options.crs)),
        nodata: options.nodata,
        sample: options.sample,
        metadata: if i == 0 {
            options.metadata.to_xml()
        } else {
            None
        },
    }
}

/// Write header, IFDs and the spilled tile data (smallest overview first) to
/// `out_path`; returns the file size.
pub(super) fn write_cog(
    out_path: &Path,
    spill: &File,
    levels: &[Level],
    options: &CogOptions,
    force_bigtiff: bool,
) -> std::io::Result<u64> {
    let mut layout = plan_layout(levels, options, force_bigtiff);
    if !layout.bigtiff && layout.total_bytes > u32::MAX as u64 {
        layout = plan_layout(levels, options, true);
    }
    let mut out = BufWriter::with_capacity(1 << 20, File::create(out_path)?);
    out.write_all(&ifd::header(layout.ifd_at[0], layout.bigtiff))?;
    for (i, level) in levels.iter().enumerate() {
        // Tiles go out in row-major order whatever order they were spilled in.
        let offsets: Vec<u64> = level
            .refs
            .iter()
            .scan(layout.data_at[i], |at, r| {
                let offset = *at + 4;
                *at += r.len + TILE_FRAME_BYTES;
                Some(offset)
            })
            .collect();
        let counts: Vec<u64> = level.refs.iter().map(|r| r.len).collect();
        let entries = ifd::image_entries(
            &image_tags(levels, i, options, &offsets, &counts),
            layout.bigtiff,
        );
        let next = layout.ifd_at.get(i + 1).copied().unwrap_or(0);
        let bytes = ifd::serialize_ifd(&entries, layout.ifd_at[i], next, layout.bigtiff);
        let end = layout
            .ifd_at
            .get(i + 1)
            .copied()
            .unwrap_or(layout.data_at[levels.len() - 1]);
        debug_assert_eq!(layout.ifd_at[i] + bytes.len() as u64, end);
        out.write_all(&bytes)?;
    }
    let mut buf = Vec::new();
    for level in levels.iter().rev() {
        for r in &level.refs {
            buf.resize(r.len as usize, 0);
            spill.read_exact_at(&mut buf, r.offset)?;
            out.write_all(&(r.len as u32).to_le_bytes())?;
            out.write_all(&buf)?;
            out.write_all(&buf[buf.len() - 4..])?;
        }
    }
    out.flush()?;
    Ok(layout.total_bytes)
}
