//! Firmware images: read the firmware ELF, report its flash and RAM footprint, and write
//! it as UF2 for the RP2040's USB mass-storage bootloader.
//!
//! UF2 (Microsoft's USB flashing format): 512-byte blocks, each carrying 256 bytes of
//! flash contents at a 256-byte aligned address, tagged with the RP2040 family id.

use std::path::Path;

use object::Endianness;
use object::elf::{EM_ARM, FileHeader32, PT_LOAD, SHF_ALLOC};
use object::read::elf::{FileHeader, ProgramHeader, SectionHeader};

/// UF2 family id of the RP2040.
pub const RP2040_FAMILY_ID: u32 = 0xe48b_ff56;
/// Flash window of the RP2040 (XIP), where loadable segments must lie.
pub const RP2040_FLASH: std::ops::Range<u32> = 0x1000_0000..0x1100_0000;

const UF2_MAGIC_START0: u32 = 0x0A32_4655;
const UF2_MAGIC_START1: u32 = 0x9E5D_5157;
const UF2_MAGIC_END: u32 = 0x0AB1_6F30;
const UF2_FLAG_FAMILY_ID: u32 = 0x0000_2000;
const UF2_PAYLOAD: usize = 256;

/// Why an image could not be read or converted.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// Not a 32-bit little-endian ARM ELF file.
    #[error("not a 32-bit little-endian ARM ELF file ({0})")]
    NotArmElf(&'static str),
    /// A header points outside the file, or holds impossible values.
    #[error("truncated or corrupt ELF: {0}")]
    Corrupt(&'static str),
    /// No loadable data for flash.
    #[error("the ELF has no loadable segment in the RP2040 flash window")]
    NothingToFlash,
    /// A loadable segment starts in the flash window but runs past its end.
    #[error(
        "a segment at {address:#010x} of {len} bytes runs past the RP2040 flash window (ends at {:#010x}): not an RP2040 image",
        RP2040_FLASH.end
    )]
    OutsideFlash {
        /// Load address.
        address: u32,
        /// Bytes.
        len: usize,
    },
    /// Two loadable segments claim the same flash.
    #[error("segments at {first:#010x} and {second:#010x} overlap in flash")]
    Overlap {
        /// The lower segment's address.
        first: u32,
        /// The segment that starts inside it.
        second: u32,
    },
}

/// A loadable piece of the image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Segment {
    /// Physical (load) address.
    pub address: u32,
    /// Contents.
    pub data: Vec<u8>,
}

/// A firmware image read from an ELF file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FirmwareImage {
    /// Loadable segments, by load address.
    pub segments: Vec<Segment>,
    /// Bytes of flash used (loadable segments in flash, initialised data included).
    pub flash_bytes: u64,
    /// Bytes of RAM used statically (`.data`, `.bss`, `.uninit`).
    pub ram_bytes: u64,
}

impl FirmwareImage {
    /// Read an ELF file.
    pub fn read(path: &Path) -> Result<Self, ImageError> {
        let bytes = std::fs::read(path).map_err(|source| ImageError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&bytes)
    }

    /// Parse ELF bytes (headers through the `object` crate, which checks every offset,
    /// size and entry size against the file). Loadable segments whose load address is in
    /// the flash window must end inside it and must not overlap, so the image is never
    /// larger than the flash it is written to.
    pub fn parse(b: &[u8]) -> Result<Self, ImageError> {
        if b.get(..4) != Some(b"\x7fELF") {
            return Err(ImageError::NotArmElf("no ELF magic"));
        }
        let header = FileHeader32::<Endianness>::parse(b).map_err(|_| {
            if b.get(4) == Some(&2) {
                ImageError::NotArmElf("not 32-bit")
            } else {
                ImageError::Corrupt("ELF header")
            }
        })?;
        let endian = header
            .endian()
            .map_err(|_| ImageError::Corrupt("ELF byte order"))?;
        if !header.is_little_endian() {
            return Err(ImageError::NotArmElf("not little-endian"));
        }
        if header.e_machine(endian) != EM_ARM {
            return Err(ImageError::NotArmElf("machine is not ARM"));
        }
        let program_headers = header
            .program_headers(endian, b)
            .map_err(|_| ImageError::Corrupt("program headers (offset, count or entry size)"))?;
        let mut found: Vec<(u32, &[u8])> = Vec::new();
        for ph in program_headers {
            if ph.p_type(endian) != PT_LOAD {
                continue;
            }
            let address = ph.p_paddr(endian);
            let data = ph
                .data(endian, b)
                .map_err(|()| ImageError::Corrupt("segment past end of file"))?;
            if data.is_empty() || !RP2040_FLASH.contains(&address) {
                continue;
            }
            if u64::from(address) + data.len() as u64 > u64::from(RP2040_FLASH.end) {
                return Err(ImageError::OutsideFlash {
                    address,
                    len: data.len(),
                });
            }
            found.push((address, data));
        }
        found.sort_by_key(|&(address, _)| address);
        for pair in found.windows(2) {
            let ((a, da), (b2, _)) = (pair[0], pair[1]);
            if u64::from(a) + da.len() as u64 > u64::from(b2) {
                return Err(ImageError::Overlap {
                    first: a,
                    second: b2,
                });
            }
        }
        // Non-overlapping and inside the 16 MiB window: at most 16 MiB is copied.
        let segments: Vec<Segment> = found
            .into_iter()
            .map(|(address, data)| Segment {
                address,
                data: data.to_vec(),
            })
            .collect();
        let flash_bytes = segments.iter().map(|s| s.data.len() as u64).sum();

        // RAM: named allocated sections in the RAM window, by section header.
        let mut ram_bytes = 0u64;
        let sections = header
            .sections(endian, b)
            .map_err(|_| ImageError::Corrupt("section headers"))?;
        for section in sections.iter() {
            let named = sections
                .section_name(endian, section)
                .is_ok_and(|n| !n.is_empty());
            let alloc = section.sh_flags(endian) & SHF_ALLOC != 0;
            let in_ram = (0x2000_0000..0x2004_2000).contains(&section.sh_addr(endian));
            if named && alloc && in_ram {
                ram_bytes += u64::from(section.sh_size(endian));
            }
        }
        if segments.is_empty() {
            return Err(ImageError::NothingToFlash);
        }
        Ok(Self {
            segments,
            flash_bytes,
            ram_bytes,
        })
    }

    /// The image as UF2 blocks for the RP2040 (gaps inside a 256-byte page filled with 0).
    pub fn to_uf2(&self) -> Vec<u8> {
        // Gather 256-byte pages.
        let mut pages: std::collections::BTreeMap<u32, [u8; UF2_PAYLOAD]> = Default::default();
        for seg in &self.segments {
            for (i, &byte) in seg.data.iter().enumerate() {
                let addr = seg.address + i as u32;
                let page = addr & !(UF2_PAYLOAD as u32 - 1);
                pages.entry(page).or_insert([0; UF2_PAYLOAD])[(addr - page) as usize] = byte;
            }
        }
        let total = pages.len() as u32;
        let mut out = Vec::with_capacity(pages.len() * 512);
        for (n, (addr, data)) in pages.iter().enumerate() {
            for word in [
                UF2_MAGIC_START0,
                UF2_MAGIC_START1,
                UF2_FLAG_FAMILY_ID,
                *addr,
                UF2_PAYLOAD as u32,
                n as u32,
                total,
                RP2040_FAMILY_ID,
            ] {
                out.extend_from_slice(&word.to_le_bytes());
            }
            out.extend_from_slice(data);
            out.resize(out.len() + (476 - UF2_PAYLOAD), 0);
            out.extend_from_slice(&UF2_MAGIC_END.to_le_bytes());
        }
        out
    }

    /// Write the UF2 file.
    pub fn write_uf2(&self, path: &Path) -> Result<usize, ImageError> {
        let uf2 = self.to_uf2();
        crate::output::write_atomic(path, &uf2).map_err(|source| ImageError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Ok(uf2.len() / 512)
    }
}

/// Largest UF2 file for the RP2040: one 512-byte block per 256 bytes of its 16 MiB flash
/// window.
pub const MAX_UF2_BYTES: u64 = (RP2040_FLASH.end - RP2040_FLASH.start) as u64 * 2;

/// Why a UF2 file would not flash this sensor.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Uf2Error {
    /// Not a whole number of 512-byte blocks, empty, or larger than flash allows.
    #[error(
        "{0} bytes is not a UF2 image for the RP2040 (a multiple of 512 bytes, at most {MAX_UF2_BYTES})"
    )]
    Size(usize),
    /// A block's framing or contents are wrong.
    #[error("block {block}: {why}")]
    Block {
        /// Block index in the file.
        block: usize,
        /// What is wrong.
        why: String,
    },
}

/// Checks every block of a UF2 file: magic numbers, the RP2040 family id, 256-byte
/// payloads at 256-byte aligned addresses inside the flash window, block numbers 0..n
/// in order with the right total. Returns the number of blocks.
pub fn check_uf2(data: &[u8]) -> Result<usize, Uf2Error> {
    if data.is_empty() || !data.len().is_multiple_of(512) || data.len() as u64 > MAX_UF2_BYTES {
        return Err(Uf2Error::Size(data.len()));
    }
    let total = data.len() / 512;
    for (block, b) in data.chunks_exact(512).enumerate() {
        let word =
            |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let fail = |why: String| Err(Uf2Error::Block { block, why });
        if word(0) != UF2_MAGIC_START0 || word(1) != UF2_MAGIC_START1 || word(127) != UF2_MAGIC_END
        {
            return fail("magic numbers missing: not a UF2 block".into());
        }
        if word(2) & UF2_FLAG_FAMILY_ID == 0 || word(7) != RP2040_FAMILY_ID {
            return fail(format!(
                "family {:#010x} is not the RP2040's ({RP2040_FAMILY_ID:#010x})",
                word(7)
            ));
        }
        let (address, size) = (word(3), word(4));
        if size != UF2_PAYLOAD as u32 || !address.is_multiple_of(UF2_PAYLOAD as u32) {
            return fail(format!(
                "{size} bytes at {address:#010x}: the RP2040 takes 256 bytes at 256-byte aligned addresses"
            ));
        }
        if !RP2040_FLASH.contains(&address) {
            return fail(format!(
                "address {address:#010x} is outside the flash window"
            ));
        }
        if word(5) as usize != block || word(6) as usize != total {
            return fail(format!(
                "numbered {} of {}, expected {block} of {total}",
                word(5),
                word(6)
            ));
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ARM ELF with one PT_LOAD segment of `data` at `addr` and no sections.
    fn tiny_elf(addr: u32, data: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; 52 + 32];
        b[..4].copy_from_slice(b"\x7fELF");
        b[4] = 1; // 32-bit
        b[5] = 1; // little-endian
        b[6] = 1; // ELF version
        b[18..20].copy_from_slice(&40u16.to_le_bytes());
        b[28..32].copy_from_slice(&52u32.to_le_bytes()); // phoff
        b[42..44].copy_from_slice(&32u16.to_le_bytes()); // phentsize
        b[44..46].copy_from_slice(&1u16.to_le_bytes()); // phnum
        let ph = 52;
        b[ph..ph + 4].copy_from_slice(&1u32.to_le_bytes());
        b[ph + 4..ph + 8].copy_from_slice(&(84u32).to_le_bytes());
        b[ph + 12..ph + 16].copy_from_slice(&addr.to_le_bytes());
        b[ph + 16..ph + 20].copy_from_slice(&(data.len() as u32).to_le_bytes());
        b.extend_from_slice(data);
        b
    }

    #[test]
    fn uf2_blocks_carry_the_data_at_the_right_addresses() {
        let data: Vec<u8> = (0..300u32).map(|i| (i % 251) as u8).collect();
        let image = FirmwareImage::parse(&tiny_elf(0x1000_0080, &data)).unwrap();
        assert_eq!(image.flash_bytes, 300);
        let uf2 = image.to_uf2();
        assert_eq!(uf2.len(), 2 * 512, "0x..80 + 300 bytes spans two pages");
        let word = |blk: usize, i: usize| {
            let at = blk * 512 + 4 * i;
            u32::from_le_bytes(uf2[at..at + 4].try_into().unwrap())
        };
        assert_eq!(word(0, 0), UF2_MAGIC_START0);
        assert_eq!(word(0, 3), 0x1000_0000);
        assert_eq!(word(1, 3), 0x1000_0100);
        assert_eq!((word(0, 5), word(0, 6)), (0, 2));
        assert_eq!(word(1, 7), RP2040_FAMILY_ID);
        assert_eq!(word(0, 127), UF2_MAGIC_END);
        assert_eq!(uf2[32 + 0x80], data[0]);
        assert_eq!(uf2[512 + 32 + (300 - 128 - 1)], data[299]);
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        assert!(matches!(
            FirmwareImage::parse(b"hello"),
            Err(ImageError::NotArmElf(_))
        ));
        assert!(matches!(
            FirmwareImage::parse(&tiny_elf(0x2000_0000, &[1, 2, 3])),
            Err(ImageError::NothingToFlash)
        ));
        let mut truncated = tiny_elf(0x1000_0000, &[1, 2, 3]);
        truncated.truncate(86);
        assert!(matches!(
            FirmwareImage::parse(&truncated),
            Err(ImageError::Corrupt(_))
        ));
    }

    #[test]
    fn hostile_headers_are_refused_before_any_large_copy() {
        // 65535 program headers of entry size 0 (each would read the same segment):
        // the entry size is checked first.
        let mut many = tiny_elf(0x1000_0000, &[1; 64]);
        many[42..44].copy_from_slice(&0u16.to_le_bytes());
        many[44..46].copy_from_slice(&u16::MAX.to_le_bytes());
        assert!(matches!(
            FirmwareImage::parse(&many),
            Err(ImageError::Corrupt(_))
        ));
        // A segment that starts in flash and runs past the 16 MiB window.
        let near_end = tiny_elf(0x10ff_ff00, &[7; 512]);
        let e = FirmwareImage::parse(&near_end).unwrap_err();
        assert!(
            matches!(e, ImageError::OutsideFlash { len: 512, .. }),
            "{e}"
        );
        // Two program headers for the same bytes.
        let mut twice = tiny_elf(0x1000_0000, &[3; 300]);
        twice[44..46].copy_from_slice(&2u16.to_le_bytes());
        let second: Vec<u8> = twice[52..84].to_vec();
        twice.splice(84..84, second);
        // The data moved 32 bytes on: point both headers at it.
        for ph in [52usize, 84] {
            twice[ph + 4..ph + 8].copy_from_slice(&116u32.to_le_bytes());
        }
        let e = FirmwareImage::parse(&twice).unwrap_err();
        assert!(matches!(e, ImageError::Overlap { .. }), "{e}");
        // A 64-bit or big-endian ELF is not an RP2040 image.
        let mut wide = tiny_elf(0x1000_0000, &[1]);
        wide[4] = 2;
        assert!(matches!(
            FirmwareImage::parse(&wide),
            Err(ImageError::NotArmElf(_))
        ));
        let mut big = tiny_elf(0x1000_0000, &[1]);
        big[5] = 2;
        assert!(FirmwareImage::parse(&big).is_err());
    }

    proptest::proptest! {
        /// Any damage to a valid UF2 file is accepted only if every block still checks
        /// out; never a panic.
        #[test]
        fn damaged_uf2_files_never_panic(at in 0usize..1024, byte in proptest::num::u8::ANY, cut in 0usize..1100) {
            let image = FirmwareImage::parse(&tiny_elf(0x1000_0080, &[9; 300])).unwrap();
            let mut uf2 = image.to_uf2();
            uf2[at] = byte;
            uf2.truncate(cut);
            if let Ok(blocks) = check_uf2(&uf2) {
                proptest::prop_assert_eq!(blocks * 512, uf2.len());
            }
        }

        /// Any damage to a valid image is an image or a typed error, never a panic or a
        /// copy larger than flash.
        #[test]
        fn damaged_elves_never_panic(at in 0usize..120, byte in proptest::num::u8::ANY, len in 0usize..400) {
            let mut b = tiny_elf(0x1000_0000, &vec![5; len]);
            let at = at.min(b.len() - 1);
            b[at] = byte;
            if let Ok(img) = FirmwareImage::parse(&b) {
                proptest::prop_assert!(img.flash_bytes <= u64::from(RP2040_FLASH.end - RP2040_FLASH.start));
            }
        }
    }

    #[test]
    fn uf2_files_are_checked_block_by_block() {
        let image = FirmwareImage::parse(&tiny_elf(0x1000_0080, &[9; 300])).unwrap();
        let uf2 = image.to_uf2();
        assert_eq!(check_uf2(&uf2), Ok(2));
        assert_eq!(check_uf2(&uf2[..700]), Err(Uf2Error::Size(700)));
        assert_eq!(check_uf2(&[]), Err(Uf2Error::Size(0)));
        let with = |at: usize, word: u32| {
            let mut u = uf2.clone();
            u[at..at + 4].copy_from_slice(&word.to_le_bytes());
            check_uf2(&u).unwrap_err().to_string()
        };
        assert!(with(512 + 28, 0xada5_2840).contains("block 1: family"));
        assert!(with(512 + 12, 0x2000_0000).contains("outside the flash"));
        assert!(with(512 + 12, 0x1000_0010).contains("aligned"));
        assert!(with(512 + 20, 0).contains("numbered 0 of 2, expected 1 of 2"));
        assert!(with(508, 0).contains("magic"));
    }
}
