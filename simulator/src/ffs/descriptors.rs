//! The bytes written to a FunctionFS `ep0` before the gadget can bind: the descriptor blob and the string blob,
//! written by hand from the Linux kernel's FunctionFS ABI (include/uapi/linux/usb/functionfs.h,
//! Documentation/usb/functionfs.rst), the USB 2.0 specification (chapter 9: interface and endpoint descriptors)
//! and USBTMC 1.0 / USB488 1.0 (interface class 0xFE, subclass 0x03, protocol 0x01; one Bulk-OUT and one Bulk-IN
//! endpoint).
//!
//! Layout (all integers little-endian):
//! - descriptors: `u32` magic 3 (v2), `u32` total length, `u32` flags (HAS_FS_DESC | HAS_HS_DESC |
//!   VIRTUAL_ADDR), `u32` full-speed count, `u32` high-speed count, then the full-speed and high-speed
//!   descriptor lists (interface, then Bulk-IN, then Bulk-OUT endpoint). With VIRTUAL_ADDR the kernel names
//!   the endpoint files by these addresses: `ep81`, `ep02`.
//! - strings: `u32` magic 2, `u32` total length, `u32` string count (1), `u32` language count (1), then the
//!   language code 0x0409 and the interface's name, NUL-terminated.
//!
//! VIRTUAL_ADDR makes the kernel hand class requests addressed to an endpoint to us with the endpoint address
//! written in these descriptors (0x81, 0x02), whatever address the controller actually assigned; the emulator's
//! own endpoint numbers are exactly those.

/// FUNCTIONFS_DESCRIPTORS_MAGIC_V2.
const DESCRIPTORS_MAGIC_V2: u32 = 3;
/// FUNCTIONFS_STRINGS_MAGIC.
const STRINGS_MAGIC: u32 = 2;
/// Flags of the v2 header: full-speed and high-speed descriptors present, endpoint addresses as written here.
const HAS_FS_DESC: u32 = 1;
const HAS_HS_DESC: u32 = 2;
const VIRTUAL_ADDR: u32 = 16;

/// USB descriptor types and the bulk transfer type (USB 2.0, tables 9-5 and 9-13).
const DT_INTERFACE: u8 = 4;
const DT_ENDPOINT: u8 = 5;
const XFER_BULK: u8 = 2;

/// USBTMC interface (USBTMC 1.0 table 43; USB488 1.0 section 4.2.2: protocol 1 = USB488).
pub const USBTMC_CLASS: u8 = 0xFE;
pub const USBTMC_SUBCLASS: u8 = 0x03;
pub const USB488_PROTOCOL: u8 = 0x01;

/// Largest bulk packet at full speed and at high speed (USB 2.0, 5.8.3).
pub const FS_BULK_PACKET: u16 = 64;
pub const HS_BULK_PACKET: u16 = 512;

fn interface() -> [u8; 9] {
    // bLength, bDescriptorType, bInterfaceNumber (renumbered by the kernel), bAlternateSetting, bNumEndpoints,
    // class, subclass, protocol, iInterface (string 1 of the string blob).
    [
        9,
        DT_INTERFACE,
        0,
        0,
        2,
        USBTMC_CLASS,
        USBTMC_SUBCLASS,
        USB488_PROTOCOL,
        1,
    ]
}

fn endpoint(address: u8, packet: u16) -> [u8; 7] {
    let [lo, hi] = packet.to_le_bytes();
    // bLength, bDescriptorType, bEndpointAddress, bmAttributes, wMaxPacketSize, bInterval (unused for bulk IN,
    // and NAK rate 0 for bulk OUT at high speed).
    [7, DT_ENDPOINT, address, XFER_BULK, lo, hi, 0]
}

fn speed(bulk_in: u8, bulk_out: u8, packet: u16) -> Vec<u8> {
    let mut v = interface().to_vec();
    v.extend_from_slice(&endpoint(bulk_in, packet));
    v.extend_from_slice(&endpoint(bulk_out, packet));
    v
}

/// The descriptor blob for a USBTMC/USB488 interface with the Bulk-IN endpoint `bulk_in` (bit 7 set) and the
/// Bulk-OUT endpoint `bulk_out`.
pub fn descriptors(bulk_in: u8, bulk_out: u8) -> Vec<u8> {
    let fs = speed(bulk_in, bulk_out, FS_BULK_PACKET);
    let hs = speed(bulk_in, bulk_out, HS_BULK_PACKET);
    let per_speed = 3u32; // interface + two endpoints
    let mut v = Vec::new();
    v.extend_from_slice(&DESCRIPTORS_MAGIC_V2.to_le_bytes());
    v.extend_from_slice(&0u32.to_le_bytes()); // length, patched below
    v.extend_from_slice(&(HAS_FS_DESC | HAS_HS_DESC | VIRTUAL_ADDR).to_le_bytes());
    v.extend_from_slice(&per_speed.to_le_bytes());
    v.extend_from_slice(&per_speed.to_le_bytes());
    v.extend_from_slice(&fs);
    v.extend_from_slice(&hs);
    let len = (v.len() as u32).to_le_bytes();
    v[4..8].copy_from_slice(&len);
    v
}

/// The string blob: one string (the interface's name) in US English.
pub fn strings(interface_name: &str) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&STRINGS_MAGIC.to_le_bytes());
    v.extend_from_slice(&0u32.to_le_bytes()); // length, patched below
    v.extend_from_slice(&1u32.to_le_bytes()); // string count
    v.extend_from_slice(&1u32.to_le_bytes()); // language count
    v.extend_from_slice(&0x0409u16.to_le_bytes());
    // A NUL inside the name would end it early: drop any.
    v.extend(interface_name.bytes().filter(|b| *b != 0));
    v.push(0);
    let len = (v.len() as u32).to_le_bytes();
    v[4..8].copy_from_slice(&len);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_descriptor_blob_has_the_v2_header_and_a_usbtmc_interface_per_speed() {
        let d = descriptors(0x81, 0x02);
        let word = |i: usize| u32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]]);
        assert_eq!(word(0), 3, "v2 magic");
        assert_eq!(word(4) as usize, d.len(), "length covers the whole blob");
        assert_eq!(word(8), 1 | 2 | 16);
        assert_eq!((word(12), word(16)), (3, 3));
        assert_eq!(d.len(), 20 + 2 * (9 + 7 + 7));
        // Full speed, then high speed: each an interface (class FE/03/01) and two bulk endpoints.
        for (start, packet) in [(20usize, 64u16), (43, 512)] {
            assert_eq!(&d[start..start + 9], &[9, 4, 0, 0, 2, 0xFE, 0x03, 0x01, 1]);
            let ep_in = &d[start + 9..start + 16];
            let ep_out = &d[start + 16..start + 23];
            assert_eq!((ep_in[2], ep_in[3]), (0x81, 2));
            assert_eq!((ep_out[2], ep_out[3]), (0x02, 2));
            assert_eq!(u16::from_le_bytes([ep_in[4], ep_in[5]]), packet);
            assert_eq!(u16::from_le_bytes([ep_out[4], ep_out[5]]), packet);
        }
    }

    #[test]
    fn the_string_blob_carries_one_nul_terminated_english_string() {
        let s = strings("PM100 USBTMC");
        assert_eq!(&s[0..4], &2u32.to_le_bytes());
        assert_eq!(u32::from_le_bytes([s[4], s[5], s[6], s[7]]) as usize, s.len());
        assert_eq!(&s[8..16], &[1, 0, 0, 0, 1, 0, 0, 0]);
        assert_eq!(&s[16..18], &[0x09, 0x04]);
        assert_eq!(&s[18..], b"PM100 USBTMC\0");
        assert_eq!(&strings("a\0b")[18..], b"ab\0");
    }
}
