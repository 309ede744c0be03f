//! The one member of a zip archive that SRTM tiles are delivered in
//! (`N39E040.SRTMGL1.hgt.zip`, `NASADEM_HGT_n39e040.zip`), streamed: opening
//! reads only the central directory at the end of the archive and the
//! member's local header, and the member is inflated (stored or Deflate) as
//! its rows are read, through a small buffer, so a tile costs no memory of
//! its size and ingest's header-only opens cost no inflating. When the
//! stream reaches the member's end its length and CRC-32 are checked, so a
//! truncated or corrupt download is refused rather than read as heights.
//!
//! Only what those archives use is read: no ZIP64 (a tile is at most 104 MB),
//! no encryption, no other compression method; each is refused by name.

use std::io::{BufReader, Read, Seek, SeekFrom, Take};

/// A member of the archive, as its central directory lists it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    pub name: String,
    method: u16,
    flags: u16,
    crc32: u32,
    compressed: u64,
    pub uncompressed: u64,
    local_header: u64,
}

const END_OF_DIRECTORY: u32 = 0x0605_4b50;
const DIRECTORY_ENTRY: u32 = 0x0201_4b50;
const LOCAL_HEADER: u32 = 0x0403_4b50;
/// A 32-bit size or offset with this value points to a ZIP64 record.
const ZIP64_MARK: u32 = u32::MAX;
const ZIP64: &str = "a ZIP64 archive (not read; unzip it first)";

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// `len` bytes of `r` from `at` (fewer at the end of the file; a corrupt
/// length allocates no more than the file holds).
fn read_at<R: Read + Seek>(r: &mut R, at: u64, len: usize) -> std::io::Result<Vec<u8>> {
    r.seek(SeekFrom::Start(at))?;
    let mut out = Vec::with_capacity(len.min(1 << 16));
    r.take(len as u64).read_to_end(&mut out)?;
    Ok(out)
}

fn io_error(e: std::io::Error) -> String {
    format!("cannot read the archive: {e}")
}

/// The members the central directory of the archive `r` lists.
pub fn members<R: Read + Seek>(r: &mut R) -> Result<Vec<Member>, String> {
    let truncated = "not a zip archive, or truncated (no end-of-directory record)";
    // the end-of-directory record: 22 bytes and a comment of up to 64 KiB
    let len = r.seek(SeekFrom::End(0)).map_err(io_error)?;
    let tail_at = len.saturating_sub(22 + u64::from(u16::MAX));
    let tail = read_at(r, tail_at, (len - tail_at) as usize).map_err(io_error)?;
    let end = (0..=tail.len().checked_sub(22).ok_or(truncated)?)
        .rev()
        .find(|&at| u32_at(&tail, at) == Some(END_OF_DIRECTORY))
        .ok_or(truncated)?;
    let count = u16_at(&tail, end + 10).unwrap_or(0);
    let (size, offset) = (
        u32_at(&tail, end + 12).unwrap_or(0),
        u32_at(&tail, end + 16).unwrap_or(0),
    );
    if size == ZIP64_MARK || offset == ZIP64_MARK || count == u16::MAX {
        return Err(ZIP64.into());
    }
    let directory = read_at(r, u64::from(offset), size as usize).map_err(io_error)?;
    let mut at = 0;
    let mut out = Vec::with_capacity(usize::from(count));
    let corrupt = || "truncated or corrupt zip central directory".to_string();
    for _ in 0..count {
        if u32_at(&directory, at) != Some(DIRECTORY_ENTRY) {
            return Err(corrupt());
        }
        let field = |o: usize| u16_at(&directory, at + o).ok_or_else(corrupt);
        let word = |o: usize| u32_at(&directory, at + o).ok_or_else(corrupt);
        let (name_len, extra_len, comment_len) = (field(28)?, field(30)?, field(32)?);
        let name_at = at + 46;
        let name = (directory.get(name_at..name_at + usize::from(name_len))).ok_or_else(corrupt)?;
        let (compressed, uncompressed, local) = (word(20)?, word(24)?, word(42)?);
        if [compressed, uncompressed, local].contains(&ZIP64_MARK) {
            return Err(ZIP64.into());
        }
        // control characters (a newline in a corrupt name) would break the
        // one-line messages that show the name
        let name: String = (String::from_utf8_lossy(name).chars())
            .map(|c| if c.is_control() { '\u{fffd}' } else { c })
            .collect();
        out.push(Member {
            name,
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

/// The bytes of a member as a stream, checked against the archive's length
/// and CRC-32 when it ends.
pub struct MemberReader<R: Read> {
    name: String,
    inner: Inner<R>,
    expected_crc: u32,
    expected_len: u64,
    crc: flate2::Crc,
    read: u64,
}

enum Inner<R: Read> {
    Stored(BufReader<Take<R>>),
    Deflate(flate2::read::DeflateDecoder<Take<R>>),
}

/// A stream of `member`'s bytes from the archive `r`.
pub fn open_member<R: Read + Seek>(mut r: R, member: &Member) -> Result<MemberReader<R>, String> {
    let name = &member.name;
    if member.flags & 1 != 0 {
        return Err(format!("{name} is encrypted"));
    }
    let truncated = || format!("{name}: truncated archive");
    let header = read_at(&mut r, member.local_header, 30).map_err(io_error)?;
    if u32_at(&header, 0) != Some(LOCAL_HEADER) {
        return Err(truncated());
    }
    let name_len = u16_at(&header, 26).ok_or_else(truncated)?;
    let extra_len = u16_at(&header, 28).ok_or_else(truncated)?;
    let data_at = member.local_header + 30 + u64::from(name_len) + u64::from(extra_len);
    r.seek(SeekFrom::Start(data_at)).map_err(io_error)?;
    let data = r.take(member.compressed);
    let inner = match member.method {
        0 => Inner::Stored(BufReader::new(data)),
        8 => Inner::Deflate(flate2::read::DeflateDecoder::new(data)),
        m => {
            let why = "only stored and Deflate are read; unzip it first";
            return Err(format!("{name}: zip compression method {m} ({why})"));
        }
    };
    Ok(MemberReader {
        name: name.clone(),
        inner,
        expected_crc: member.crc32,
        expected_len: member.uncompressed,
        crc: flate2::Crc::new(),
        read: 0,
    })
}

impl<R: Read> MemberReader<R> {
    /// Fill `buf` with the next bytes of the member; at its end, check its
    /// length and CRC-32.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), String> {
        let name = &self.name;
        if self.read + buf.len() as u64 > self.expected_len {
            return Err(format!("{name}: read past the member's end"));
        }
        let got = match &mut self.inner {
            Inner::Stored(r) => r.read_exact(buf),
            Inner::Deflate(r) => r.read_exact(buf),
        };
        got.map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => format!("{name}: truncated archive"),
            _ => format!("{name}: corrupt Deflate data ({e})"),
        })?;
        self.crc.update(buf);
        self.read += buf.len() as u64;
        if self.read == self.expected_len && self.crc.sum() != self.expected_crc {
            return Err(format!(
                "{name}: CRC-32 {:08x} where the archive says {:08x}: corrupt",
                self.crc.sum(),
                self.expected_crc
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use std::io::{Cursor, Write};

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

    /// The whole member, read in pieces of `piece` bytes.
    fn extract(zip: &[u8], member: &Member, piece: usize) -> Result<Vec<u8>, String> {
        let mut stream = open_member(Cursor::new(zip), member)?;
        let mut out = Vec::new();
        while out.len() < member.uncompressed as usize {
            let mut buf = vec![0u8; piece.min(member.uncompressed as usize - out.len())];
            stream.read_exact(&mut buf)?;
            out.extend(buf);
        }
        Ok(out)
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
            let list = members(&mut Cursor::new(&zip)).unwrap();
            let names: Vec<&str> = list.iter().map(|m| m.name.as_str()).collect();
            assert_eq!(names, ["readme.txt", "N39E040.hgt"]);
            for piece in [1, 7, 2402, 10_000] {
                assert_eq!(extract(&zip, &list[1], piece).unwrap(), heights, "{piece}");
            }
            assert_eq!(extract(&zip, &list[0], 3).unwrap(), b"tile");
        }
    }

    #[test]
    fn truncated_and_corrupt_archives_are_refused() {
        let heights: Vec<u8> = (0..5000u32)
            .flat_map(|i| (i as u16).to_be_bytes())
            .collect();
        for deflate in [false, true] {
            let zip = archive(&[("N39E040.hgt", &heights)], deflate);
            // cut anywhere: the end-of-directory record is missing
            for cut in [0, 21, zip.len() / 3, zip.len() - 10] {
                let err = members(&mut Cursor::new(&zip[..cut])).unwrap_err();
                assert!(err.contains("truncated"), "{err}");
            }
            // one flipped byte in the data: Deflate or the CRC catches it
            let mut bad = zip.clone();
            bad[60] ^= 0x5a;
            let member = &members(&mut Cursor::new(&bad)).unwrap()[0];
            let err = extract(&bad, member, 1000).unwrap_err();
            assert!(err.contains("corrupt"), "{err}");
            // the data cut short (the directory kept): the stream ends early
            let member = &members(&mut Cursor::new(&zip)).unwrap()[0];
            let err = extract(&zip[..200], member, 1000).unwrap_err();
            assert!(
                err.contains("truncated") || err.contains("corrupt"),
                "{err}"
            );
        }
        // another compression method
        let zip = archive(&[("N39E040.hgt", &heights)], true);
        let mut other = members(&mut Cursor::new(&zip)).unwrap()[0].clone();
        other.method = 12;
        let err = open_member(Cursor::new(&zip), &other).err().unwrap();
        assert!(err.contains("method 12"), "{err}");
    }
}
