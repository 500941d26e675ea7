//! Where a recording's top-level records lie, read from their opcode and length fields
//! alone (nothing decompressed), for the reader to go on past a damaged chunk and to
//! find the channels the file's summary repeats.
//!
//! An MCAP file is its magic, then records of `opcode (u8) · length (u64 LE) · body`.
//! A chunk's body can be damaged (a flipped bit fails its checksum or its
//! decompression) while its length field, and so every record after it, is sound:
//! walking the lengths from a known boundary tells where the chunk ends. A walk that
//! meets an unknown opcode or a length past the end of the file is not trusted.

use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};

use mcap::records::op;

/// Bytes of a record's opcode and length.
const RECORD_HEAD: u64 = 9;
/// Most chunk places a summary gives (a hostile summary cannot take more memory).
const MAX_CHUNKS: usize = 1 << 20;
/// Largest channel record read from a summary (a topic, an encoding, a little metadata).
const MAX_CHANNEL_BODY: u64 = 64 << 10;
/// A footer record: head, summary start, summary offset start, summary CRC.
const FOOTER_LEN: u64 = RECORD_HEAD + 8 + 8 + 4;

/// One top-level record's place in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Span {
    /// Its opcode.
    pub opcode: u8,
    /// Offset of its opcode.
    pub start: u64,
    /// Offset just past its body.
    pub end: u64,
}

/// Reads `N` bytes at `offset`.
fn read_at<const N: usize>(file: &mut File, offset: u64) -> std::io::Result<[u8; N]> {
    let mut buf = [0u8; N];
    file.seek(SeekFrom::Start(offset))?;
    file.read_exact(&mut buf)?;
    Ok(buf)
}

/// The top-level record starting at `start` in a file of `len` bytes, or `None` when its
/// fields cannot be a record (an unknown opcode, a body running past the end).
fn span_at(file: &mut File, len: u64, start: u64) -> std::io::Result<Option<Span>> {
    if len.saturating_sub(start) < RECORD_HEAD {
        return Ok(None);
    }
    let head: [u8; 9] = read_at(file, start)?;
    let opcode = head[0];
    let body = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
    // The specification's records, and private ones (0x80 and up).
    if !(op::HEADER..=op::DATA_END).contains(&opcode) && opcode < 0x80 {
        return Ok(None);
    }
    Ok(start
        .checked_add(RECORD_HEAD)
        .and_then(|s| s.checked_add(body))
        .filter(|&end| end <= len)
        .map(|end| Span { opcode, start, end }))
}

/// The top-level record that holds byte `at`, walking from `from` (the start of a
/// record) in a file of `len` bytes; `None` when the walk meets something that is not a
/// record before reaching it, or `at` lies before `from`.
pub fn record_holding(
    file: &mut File,
    len: u64,
    from: u64,
    at: u64,
) -> std::io::Result<Option<Span>> {
    let mut start = from;
    while start <= at {
        let Some(span) = span_at(file, len, start)? else {
            return Ok(None);
        };
        if at < span.end {
            return Ok(Some(span));
        }
        start = span.end;
    }
    Ok(None)
}

/// `true` when the chunk `span` is whole by its own fields (its header and compressed
/// records fill its body exactly) and a record starts where it ends (or the file ends
/// there): then its length field, which says where reading goes on, is sound.
pub fn chunk_is_consistent(file: &mut File, len: u64, span: Span) -> std::io::Result<bool> {
    // start, end, uncompressed size (u64 each), uncompressed CRC (u32), then the
    // compression string's length.
    const FIXED: u64 = 8 + 8 + 8 + 4;
    let body = span.end - span.start - RECORD_HEAD;
    if span.opcode != op::CHUNK || body < FIXED + 4 + 8 {
        return Ok(false);
    }
    let at = span.start + RECORD_HEAD + FIXED;
    let compression: [u8; 4] = read_at(file, at)?;
    let compression = u64::from(u32::from_le_bytes(compression));
    let Some(size_at) = (at + 4).checked_add(compression) else {
        return Ok(false);
    };
    if size_at + 8 > span.end {
        return Ok(false);
    }
    let compressed = u64::from_le_bytes(read_at(file, size_at)?);
    if size_at
        .checked_add(8)
        .and_then(|s| s.checked_add(compressed))
        != Some(span.end)
    {
        return Ok(false);
    }
    Ok(span.end == len || span_at(file, len, span.end)?.is_some())
}

/// `true` when `span` (a chunk's place as an index gives it) is where a chunk record
/// starts: its opcode and length field say so, and it is whole by its fields.
pub fn is_chunk_at(file: &mut File, len: u64, span: Span) -> std::io::Result<bool> {
    Ok(span_at(file, len, span.start)? == Some(span) && chunk_is_consistent(file, len, span)?)
}

/// What a finished file's summary section repeats that the reader may need after
/// damage.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    /// Channels: id → (topic, message encoding).
    pub channels: HashMap<u16, (String, String)>,
    /// Every chunk's place (from the chunk index records), in file order.
    pub chunks: Vec<Span>,
}

/// The summary section of a finished file of `len` bytes; empty when the file has no
/// summary, or its footer is not sound (records that are not sound end it). Bodies longer
/// than `limit` are not read.
pub fn summary(file: &mut File, len: u64, limit: usize) -> std::io::Result<Summary> {
    let mut found = Summary::default();
    let magic = mcap::MAGIC.len() as u64;
    let Some(footer_at) = len.checked_sub(magic + FOOTER_LEN) else {
        return Ok(found);
    };
    let footer: [u8; FOOTER_LEN as usize] = read_at(file, footer_at)?;
    let body = u64::from_le_bytes(footer[1..9].try_into().expect("8 bytes"));
    let summary_start = u64::from_le_bytes(footer[9..17].try_into().expect("8 bytes"));
    if footer[0] != op::FOOTER || body != FOOTER_LEN - RECORD_HEAD || summary_start < magic {
        return Ok(found);
    }
    let mut start = summary_start;
    while start < footer_at {
        let Some(span) = span_at(file, footer_at, start)? else {
            break;
        };
        let body_len = span.end - span.start - RECORD_HEAD;
        let body_at = span.start + RECORD_HEAD;
        // A chunk index starts with two times, then the chunk's start and length: only
        // those are read. At most one index per chunk the file could hold.
        if span.opcode == op::CHUNK_INDEX && body_len >= 32 && found.chunks.len() < MAX_CHUNKS {
            let place: [u8; 16] = read_at(file, body_at + 16)?;
            let chunk_start = u64::from_le_bytes(place[..8].try_into().expect("8 bytes"));
            let chunk_len = u64::from_le_bytes(place[8..].try_into().expect("8 bytes"));
            if let Some(end) = chunk_start.checked_add(chunk_len).filter(|&e| e <= len) {
                found.chunks.push(Span {
                    opcode: op::CHUNK,
                    start: chunk_start,
                    end,
                });
            }
        }
        if span.opcode == op::CHANNEL
            && body_len <= MAX_CHANNEL_BODY.min(limit as u64)
            && found.channels.len() < usize::from(u16::MAX)
        {
            let mut body = vec![0u8; body_len as usize];
            file.seek(SeekFrom::Start(body_at))?;
            file.read_exact(&mut body)?;
            if let Ok(mcap::records::Record::Channel(c)) = mcap::parse_record(op::CHANNEL, &body) {
                found
                    .channels
                    .insert(c.id, (c.topic.to_string(), c.message_encoding.to_string()));
            }
        }
        start = span.end;
    }
    found.chunks.sort_by_key(|c| c.start);
    Ok(found)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    /// A chunked file: the walk finds each chunk's bounds from the start, and every
    /// record it names begins where the previous one ended; the summary gives the
    /// channel; a length field past the end stops the walk.
    #[test]
    fn walks_records_and_reads_the_summary() {
        let path =
            std::env::temp_dir().join(format!("stereotac-layout-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(1024))
            .create(file)
            .unwrap();
        let channel = w
            .add_channel(0, "/a/topic", "json", &BTreeMap::new())
            .unwrap();
        for i in 0..500u64 {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, b"{\"i\": 12345}")
                .unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let bytes = std::fs::read(&path).unwrap();
        let len = bytes.len() as u64;
        let mut file = File::open(&path).unwrap();
        let mut at = 8u64;
        let mut chunks = 0;
        while let Some(span) = record_holding(&mut file, len, 8, at).unwrap() {
            assert_eq!(span.start, at);
            assert_eq!(
                span.end - span.start - 9,
                u64::from_le_bytes(bytes[at as usize + 1..at as usize + 9].try_into().unwrap())
            );
            chunks += usize::from(span.opcode == op::CHUNK);
            if span.opcode == op::FOOTER {
                break;
            }
            at = span.end;
        }
        assert!(chunks > 5, "{chunks} chunks");
        // Every chunk is whole by its fields; one whose length field was changed is not.
        let mut at = 8u64;
        let mut first_chunk = None;
        while let Some(span) = record_holding(&mut file, len, 8, at).unwrap() {
            if span.opcode == op::CHUNK {
                assert!(chunk_is_consistent(&mut file, len, span).unwrap());
                first_chunk.get_or_insert(span);
            }
            if span.opcode == op::FOOTER {
                break;
            }
            at = span.end;
        }
        let chunk = first_chunk.unwrap();
        for shorter in [1, 8, 100] {
            let cut = Span {
                end: chunk.end - shorter,
                ..chunk
            };
            assert!(
                !chunk_is_consistent(&mut file, len, cut).unwrap(),
                "{shorter}"
            );
        }
        // Byte 10 lies in the first record (the header).
        let first = record_holding(&mut file, len, 8, 10).unwrap().unwrap();
        assert_eq!((first.opcode, first.start), (op::HEADER, 8));
        assert!(first.end > 10);
        assert_eq!(record_holding(&mut file, len, 108, 50).unwrap(), None);
        let found = summary(&mut file, len, 1 << 20).unwrap();
        assert_eq!(
            found.channels.get(&channel),
            Some(&("/a/topic".to_string(), "json".to_string()))
        );
        // The summary indexes every chunk the walk found, each whole by its fields.
        assert_eq!(found.chunks.len(), chunks);
        for c in &found.chunks {
            assert!(is_chunk_at(&mut file, len, *c).unwrap());
            // One byte off is not a chunk's place.
            let off = Span {
                start: c.start + 1,
                ..*c
            };
            assert!(!is_chunk_at(&mut file, len, off).unwrap());
        }
        // A length field that runs past the end: not a record.
        let mut broken = bytes.clone();
        broken[9..17].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&path, &broken).unwrap();
        let mut file = File::open(&path).unwrap();
        assert_eq!(record_holding(&mut file, len, 8, 2000).unwrap(), None);
        // No footer: no summary.
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        let mut file = File::open(&path).unwrap();
        let half = len / 2;
        assert_eq!(
            summary(&mut file, half, 1 << 20).unwrap(),
            Summary::default()
        );
        let _ = std::fs::remove_file(&path);
    }
}
