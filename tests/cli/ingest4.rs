//! Damaged Deflate blocks of a predictor-3 float file (the encoding the
//! direct codec inflates with libdeflate, falling back to zlib-rs to name the
//! fault): a block cut short is a truncated file, a block with a broken zlib
//! header is a corrupt one; both exit with code 2 and name the file and the
//! block. An undamaged copy ingests.

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::util::{bin, fixtures, text};

const SOURCE: &str = "geotiff/f32_tile_deflate_p3.tif";

/// Tags 324 (TileOffsets) and 325 (TileByteCounts) of the first IFD of a
/// classic little-endian TIFF: per tag, its value type, and where its values start.
fn tile_tables(bytes: &[u8]) -> [(u16, usize); 2] {
    let u16_at = |at: usize| u16::from_le_bytes([bytes[at], bytes[at + 1]]);
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(&bytes[..4], b"II*\0", "a classic little-endian TIFF");
    let ifd = u32_at(4) as usize;
    let mut found = [(0u16, 0usize); 2];
    for i in 0..u16_at(ifd) as usize {
        let entry = ifd + 2 + 12 * i;
        let (tag, kind, count) = (u16_at(entry), u16_at(entry + 2), u32_at(entry + 4));
        let size = if kind == 3 { 2 } else { 4 };
        let values = if count as usize * size <= 4 {
            entry + 8
        } else {
            u32_at(entry + 8) as usize
        };
        if tag == 324 || tag == 325 {
            found[(tag - 324) as usize] = (kind, values);
        }
    }
    assert!(found.iter().all(|&(kind, _)| kind == 3 || kind == 4));
    found
}

/// Value `i` of a SHORT (3) or LONG (4) table.
fn table_value(bytes: &[u8], (kind, at): (u16, usize), i: usize) -> usize {
    if kind == 3 {
        u16::from_le_bytes([bytes[at + 2 * i], bytes[at + 2 * i + 1]]) as usize
    } else {
        u32::from_le_bytes(bytes[at + 4 * i..at + 4 * i + 4].try_into().unwrap()) as usize
    }
}

fn set_table_value(bytes: &mut [u8], (kind, at): (u16, usize), i: usize, v: usize) {
    if kind == 3 {
        bytes[at + 2 * i..at + 2 * i + 2].copy_from_slice(&(v as u16).to_le_bytes());
    } else {
        bytes[at + 4 * i..at + 4 * i + 4].copy_from_slice(&(v as u32).to_le_bytes());
    }
}

/// The fixture written to `dir/name` after `damage` edits its bytes.
fn damaged(dir: &Path, name: &str, damage: impl FnOnce(&mut Vec<u8>)) -> PathBuf {
    let mut bytes = std::fs::read(fixtures().join(SOURCE)).unwrap();
    damage(&mut bytes);
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn ingest(input: &Path, store: &Path) -> Output {
    bin()
        .arg("ingest")
        .arg(input)
        .arg("--store")
        .arg(store)
        .arg("-q")
        .output()
        .unwrap()
}

#[test]
fn damaged_deflate_blocks_are_truncated_or_corrupt_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let intact = damaged(dir.path(), "intact.tif", |_| {});
    let out = ingest(&intact, &dir.path().join("intact.zarr"));
    assert!(out.status.success(), "{}", text(&out.stderr));

    // Block 1's byte count halved: its zlib stream ends before its data.
    let short = damaged(dir.path(), "short.tif", |b| {
        let [_, counts] = tile_tables(b);
        let half = table_value(b, counts, 1) / 2;
        set_table_value(b, counts, 1, half);
    });
    let out = ingest(&short, &dir.path().join("short.zarr"));
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("short.tif") && err.contains("truncated") && err.contains("block (1, 0)"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");

    // Block 1's zlib header overwritten.
    let broken = damaged(dir.path(), "broken.tif", |b| {
        let [offsets, _] = tile_tables(b);
        let at = table_value(b, offsets, 1);
        b[at..at + 4].fill(0xff);
    });
    let out = ingest(&broken, &dir.path().join("broken.zarr"));
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("broken.tif") && err.contains("corrupt") && err.contains("block (1, 0)"),
        "{err}"
    );
    // Nothing of a refused input is committed.
    for (store, id) in [("short.zarr", "short"), ("broken.zarr", "broken")] {
        assert!(!dir.path().join(store).join(id).exists(), "{store}/{id}");
    }
}
