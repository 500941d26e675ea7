//! Firmware images: read the firmware ELF, report its flash and RAM footprint, and write
//! it as UF2 for the RP2040's USB mass-storage bootloader.
//!
//! UF2 (Microsoft's USB flashing format): 512-byte blocks, each carrying 256 bytes of
//! flash contents at a 256-byte aligned address, tagged with the RP2040 family id.

use std::path::Path;

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
    /// A header points outside the file.
    #[error("truncated or corrupt ELF: {0}")]
    Corrupt(&'static str),
    /// No loadable data for flash.
    #[error("the ELF has no loadable segment in the RP2040 flash window")]
    NothingToFlash,
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

fn u16_at(b: &[u8], at: usize) -> Result<u16, ImageError> {
    b.get(at..at + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or(ImageError::Corrupt("header past end of file"))
}

fn u32_at(b: &[u8], at: usize) -> Result<u32, ImageError> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or(ImageError::Corrupt("header past end of file"))
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

    /// Parse ELF bytes.
    pub fn parse(b: &[u8]) -> Result<Self, ImageError> {
        if b.get(..4) != Some(b"\x7fELF") {
            return Err(ImageError::NotArmElf("no ELF magic"));
        }
        if b.len() < 52 {
            return Err(ImageError::Corrupt("file shorter than an ELF header"));
        }
        if b[4] != 1 || b[5] != 1 {
            return Err(ImageError::NotArmElf("not 32-bit little-endian"));
        }
        if u16_at(b, 18)? != 40 {
            return Err(ImageError::NotArmElf("machine is not ARM"));
        }
        let phoff = u32_at(b, 28)? as usize;
        let shoff = u32_at(b, 32)? as usize;
        let phentsize = usize::from(u16_at(b, 42)?);
        let phnum = usize::from(u16_at(b, 44)?);
        let shentsize = usize::from(u16_at(b, 46)?);
        let shnum = usize::from(u16_at(b, 48)?);
        let shstrndx = usize::from(u16_at(b, 50)?);

        let mut segments = Vec::new();
        for i in 0..phnum {
            let h = phoff + i * phentsize;
            const PT_LOAD: u32 = 1;
            if u32_at(b, h)? != PT_LOAD {
                continue;
            }
            let offset = u32_at(b, h + 4)? as usize;
            let paddr = u32_at(b, h + 12)?;
            let filesz = u32_at(b, h + 16)? as usize;
            if filesz == 0 || !RP2040_FLASH.contains(&paddr) {
                continue;
            }
            let data = b
                .get(offset..offset + filesz)
                .ok_or(ImageError::Corrupt("segment past end of file"))?;
            segments.push(Segment {
                address: paddr,
                data: data.to_vec(),
            });
        }
        segments.sort_by_key(|s| s.address);
        let flash_bytes = segments.iter().map(|s| s.data.len() as u64).sum();

        // RAM: allocated sections in the RAM window, by section header.
        let mut ram_bytes = 0u64;
        if shnum > 0 && shstrndx < shnum {
            let strtab_off = u32_at(b, shoff + shstrndx * shentsize + 16)? as usize;
            for i in 0..shnum {
                let h = shoff + i * shentsize;
                let name_off = u32_at(b, h)? as usize;
                let flags = u32_at(b, h + 8)?;
                let addr = u32_at(b, h + 12)?;
                let size = u32_at(b, h + 20)?;
                const SHF_ALLOC: u32 = 2;
                let name = b
                    .get(strtab_off + name_off..)
                    .and_then(|s| s.split(|&c| c == 0).next())
                    .unwrap_or_default();
                let in_ram = (0x2000_0000..0x2004_2000).contains(&addr);
                if flags & SHF_ALLOC != 0 && in_ram && !name.is_empty() {
                    ram_bytes += u64::from(size);
                }
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
        std::fs::write(path, &uf2).map_err(|source| ImageError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Ok(uf2.len() / 512)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ARM ELF with one PT_LOAD segment of `data` at `addr` and no sections.
    fn tiny_elf(addr: u32, data: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; 52 + 32];
        b[..4].copy_from_slice(b"\x7fELF");
        b[4] = 1;
        b[5] = 1;
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
        let word = |blk: usize, i: usize| u32_at(&uf2, blk * 512 + 4 * i).unwrap();
        assert_eq!(word(0, 0), UF2_MAGIC_START0);
        assert_eq!(word(0, 3), 0x1000_0000);
        assert_eq!(word(1, 3), 0x1000_0100);
        assert_eq!((word(0, 5), word(0, 6)), (0, 2));
        assert_eq!(word(1, 7), RP2040_FAMILY_ID);
        assert_eq!(u32_at(&uf2, 512 - 4).unwrap(), UF2_MAGIC_END);
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
}
