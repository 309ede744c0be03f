//! The one member of a zip archive that SRTM tiles are delivered in
//! (`N39E040.SRTMGL1.hgt.zip`, `NASADEM_HGT_n39e040.zip`): the central
//! directory is read from the end of the archive, the member is inflated
//! (stored or Deflate) and its length and CRC-32 are checked, so a truncated
//! or corrupt download is refused rather than read as heights.
//!
//! Only what those archives use is read: no ZIP64 (a tile is at most 104 MB),
//! no encryption, no other compression method; each is refused by name.

use std::io::Read;

/// A member of the archive, as its central directory lists it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    pub name: String,
    method: u16,
    flags: u16,
    crc32: u32,
    compressed: u64,
    uncompressed: u64,
    local_header: u64,
}

const END_OF_DIRECTORY: u32 = 0x0605_4b50;
const DIRECTORY_ENTRY: u32 = 0x0201_4b50;
const LOCAL_HEADER: u32 = 0x0403_4b50;
/// A 32-bit size or offset with this value points to a ZIP64 record.
const ZIP64_MARK: u32 = u32::MAX;

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The members the central directory of `archive` lists.
pub fn members(archive: &[u8]) -> Result<Vec<Member>, String> {
    // the end-of-directory record: 22 bytes and a comment of up to 64 KiB
    let lowest = archive.len().saturating_sub(22 + usize::from(u16::MAX));
    let end = (lowest..=archive.len().saturating_sub(22))
        .rev()
        .find(|&at| u32_at(archive, at) == Some(END_OF_DIRECTORY))
        .ok_or("not a zip archive, or truncated (no end-of-directory record)")?;
    let count = u16_at(archive, end + 10).unwrap_or(0);
    let (size, offset) = (
        u32_at(archive, end + 12).unwrap_or(0),
        u32_at(archive, end + 16).unwrap_or(0),
    );
    if size == ZIP64_MARK || offset == ZIP64_MARK || count == u16::MAX {
        return Err("a ZIP64 archive (not read; unzip it first)".into());
    }
    let mut at = offset as usize;
    let mut out = Vec::with_capacity(usize::from(count));
    for _ in 0..count {
        let truncated = || "truncated or corrupt zip central directory".to_string();
        if u32_at(archive, at) != Some(DIRECTORY_ENTRY) {
            return Err(truncated());
        }
        let field = |o: usize| u16_at(archive, at + o).ok_or_else(truncated);
        let word = |o: usize| u32_at(archive, at + o).ok_or_else(truncated);
        let (name_len, extra_len, comment_len) = (field(28)?, field(30)?, field(32)?);
        let name_at = at + 46;
        let name = archive
            .get(name_at..name_at + usize::from(name_len))
            .ok_or_else(truncated)?;
        let (compressed, uncompressed, local) = (word(20)?, word(24)?, word(42)?);
        if [compressed, uncompressed, local].contains(&ZIP64_MARK) {
            return Err("a ZIP64 archive (not read; unzip it first)".into());
        }
        out.push(Member {
            name: String::from_utf8_lossy(name).into_owned(),
            flags: field(8)?,
            method: field(10)?,
            crc32: word(16)?,
            compressed: u64::from(compressed),
            uncompressed: u64::from(uncompressed),
            local_header: u64::from(local),
        });
        at = name_at + usize::from(name_len) + usize::from(extra_len) + usize::from(comment_len);
    }
    Ok(out)
}

/// The bytes of `member`, inflated and checked against its length and CRC-32.
pub fn extract(archive: &[u8], member: &Member) -> Result<Vec<u8>, String> {
    let name = &member.name;
    if member.flags & 1 != 0 {
        return Err(format!("{name} is encrypted"));
    }
    let at = member.local_header as usize;
    let truncated = || format!("{name}: truncated archive");
    if u32_at(archive, at) != Some(LOCAL_HEADER) {
        return Err(truncated());
    }
    let name_len = u16_at(archive, at + 26).ok_or_else(truncated)?;
    let extra_len = u16_at(archive, at + 28).ok_or_else(truncated)?;
    let data_at = at + 30 + usize::from(name_len) + usize::from(extra_len);
    let data = archive
        .get(data_at..data_at + member.compressed as usize)
        .ok_or_else(truncated)?;
    let expected = member.uncompressed as usize;
    let bytes = match member.method {
        0 => data.to_vec(),
        8 => {
            let mut out = Vec::with_capacity(expected);
            flate2::read::DeflateDecoder::new(data)
                .take(member.uncompressed + 1)
                .read_to_end(&mut out)
                .map_err(|e| format!("{name}: corrupt Deflate data ({e})"))?;
            out
        }
        m => return Err(format!(
            "{name}: zip compression method {m} (only stored and Deflate are read; unzip it first)"
        )),
    };
    if bytes.len() != expected {
        return Err(format!(
            "{name}: {} bytes inflated where the archive says {expected}: corrupt",
            bytes.len()
        ));
    }
    let mut crc = flate2::Crc::new();
    crc.update(&bytes);
    if crc.sum() != member.crc32 {
        return Err(format!(
            "{name}: CRC-32 {:08x} where the archive says {:08x}: corrupt",
            crc.sum(),
            member.crc32
        ));
    }
    Ok(bytes)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use std::io::Write;

    /// A zip archive of `files` (Deflate when `deflate`, else stored), as
    /// Info-ZIP and Python's zipfile write them.
    pub fn archive(files: &[(&str, &[u8])], deflate: bool) -> Vec<u8> {
        let (mut out, mut directory) = (Vec::new(), Vec::new());
        for (name, bytes) in files {
            let data = if deflate {
                let mut e = flate2::write::DeflateEncoder::new(Vec::new(), Default::default());
                e.write_all(bytes).unwrap();
                e.finish().unwrap()
            } else {
                bytes.to_vec()
            };
            let mut crc = flate2::Crc::new();
            crc.update(bytes);
            let method: u16 = if deflate { 8 } else { 0 };
            let offset = out.len() as u32;
            let common = |v: &mut Vec<u8>| {
                v.extend(20u16.to_le_bytes()); // version needed
                v.extend(0u16.to_le_bytes()); // flags
                v.extend(method.to_le_bytes());
                v.extend([0u8; 4]); // time, date
                v.extend(crc.sum().to_le_bytes());
                v.extend((data.len() as u32).to_le_bytes());
                v.extend((bytes.len() as u32).to_le_bytes());
                v.extend((name.len() as u16).to_le_bytes());
                v.extend(0u16.to_le_bytes()); // extra
            };
            out.extend(LOCAL_HEADER.to_le_bytes());
            common(&mut out);
            out.extend(name.as_bytes());
            out.extend(&data);
            directory.extend(DIRECTORY_ENTRY.to_le_bytes());
            directory.extend(20u16.to_le_bytes()); // made by
            common(&mut directory);
            directory.extend([0u8; 6]); // comment length, disk, internal attributes
            directory.extend([0u8; 4]); // external attributes
            directory.extend(offset.to_le_bytes());
            directory.extend(name.as_bytes());
        }
        let at = out.len() as u32;
        out.extend(&directory);
        out.extend(END_OF_DIRECTORY.to_le_bytes());
        out.extend([0u8; 4]);
        out.extend((files.len() as u16).to_le_bytes());
        out.extend((files.len() as u16).to_le_bytes());
        out.extend((directory.len() as u32).to_le_bytes());
        out.extend(at.to_le_bytes());
        out.extend(0u16.to_le_bytes());
        out
    }

    #[test]
    fn members_round_trip_stored_and_deflated() {
        let heights: Vec<u8> = (0..5000u32)
            .flat_map(|i| ((i % 977) as u16).to_be_bytes())
            .collect();
        for deflate in [false, true] {
            let zip = archive(
                &[("readme.txt", b"tile"), ("N39E040.hgt", &heights)],
                deflate,
            );
            let list = members(&zip).unwrap();
            let names: Vec<&str> = list.iter().map(|m| m.name.as_str()).collect();
            assert_eq!(names, ["readme.txt", "N39E040.hgt"]);
            assert_eq!(extract(&zip, &list[1]).unwrap(), heights);
            assert_eq!(extract(&zip, &list[0]).unwrap(), b"tile");
        }
    }

    #[test]
    fn truncated_and_corrupt_archives_are_refused() {
        let heights: Vec<u8> = (0..5000u32)
            .flat_map(|i| (i as u16).to_be_bytes())
            .collect();
        let zip = archive(&[("N39E040.hgt", &heights)], true);
        // cut anywhere: the end-of-directory record or the data is missing
        for cut in [zip.len() / 3, zip.len() - 10] {
            let err = members(&zip[..cut]).unwrap_err();
            assert!(err.contains("truncated"), "{err}");
        }
        // one flipped byte in the data: Deflate or the CRC catches it
        let mut bad = zip.clone();
        bad[60] ^= 0x5a;
        let member = &members(&bad).unwrap()[0];
        let err = extract(&bad, member).unwrap_err();
        assert!(err.contains("corrupt"), "{err}");
        // another compression method
        let mut other = members(&zip).unwrap()[0].clone();
        other.method = 12;
        let err = extract(&zip, &other).unwrap_err();
        assert!(err.contains("method 12"), "{err}");
    }
}
