//! Issue 7, image format: an image packed and signed with the development key verifies, every refusal has its
//! typed error (bad CRC, bad signature, another key, wrong hardware id, truncated, oversized, trailing data),
//! from bytes, streamed into slot B, and in flash; and the development key compiled into the firmware is the
//! one in `keys/`.

use crate::support::*;
use firmware::boot::image::{ImageError, ImageHeader, HARDWARE_ID, HEADER_LEN, HEADER_OFFSET, MAX_PAYLOAD_LEN};
use firmware::boot::keys::DEV_PUBLIC_KEY;
use firmware::boot::sign::public_key;
use firmware::boot::update::{Download, Phase, UpdateError};
use firmware::boot::verify::{verify_bytes, verify_in_flash};
use firmware::hal::flash::NorFlash;
use hal_sim::flash::SimFlash;

const LEN: usize = 40 * 1024;

#[test]
fn the_compiled_in_key_is_the_dev_key_in_the_repository() {
    let pub_file =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../keys/dev-signing-key.pub")).unwrap();
    assert_eq!(hex32(&pub_file), DEV_PUBLIC_KEY);
    assert_eq!(public_key(&dev_seed()), DEV_PUBLIC_KEY, "the secret seed does not belong to the public key");
}

#[test]
fn an_image_signed_with_the_dev_key_verifies_from_bytes_and_in_flash() {
    let img = image(LEN, 0x0102_0003);
    let h = verify_bytes(&img, &trust()).expect("valid image");
    assert_eq!((h.firmware_version, h.software_id, h.payload_len), (0x0102_0003, 0x0102_0000, LEN as u32));
    assert_eq!(h.version_str(), b"v0102");

    let mut slot = SimFlash::new(SLOT_SECTOR, 3, 4);
    factory_install(&mut slot, &img);
    for buf_len in [1usize, 7, 256, 4096] {
        let mut buf = vec![0u8; buf_len];
        assert_eq!(verify_in_flash(&mut slot, HEADER_OFFSET, &trust(), &mut buf), Ok(h), "buffer {buf_len}");
    }
}

/// Every refusal, from the bytes of the file.
#[test]
fn every_refusal_from_bytes_is_typed() {
    let good = image(LEN, 0x0200_0000);
    let t = trust();

    let mut bad_crc = good.clone();
    bad_crc[HEADER_LEN as usize + 1000] ^= 0x01;
    assert!(matches!(verify_bytes(&bad_crc, &t), Err(ImageError::Crc { .. })));

    // Payload and CRC changed consistently, signature left: the signature check catches it.
    let mut forged = good.clone();
    forged[HEADER_LEN as usize + 1000] ^= 0x01;
    let crc = firmware::boot::crc32::checksum(&forged[HEADER_LEN as usize..]);
    forged[24..28].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(verify_bytes(&forged, &t), Err(ImageError::BadSignature));

    let mut bad_sig = good.clone();
    bad_sig[64 + 5] ^= 0x80;
    assert_eq!(verify_bytes(&bad_sig, &t), Err(ImageError::BadSignature));

    let other_key = image_signed_with(LEN, 0x0200_0000, HARDWARE_ID, &[0x42; 32]);
    assert_eq!(verify_bytes(&other_key, &t), Err(ImageError::BadSignature));

    let other_hw = image_signed_with(LEN, 0x0200_0000, 0x0F40_9999, &dev_seed());
    assert_eq!(
        verify_bytes(&other_hw, &t),
        Err(ImageError::WrongHardware { expected: HARDWARE_ID, found: 0x0F40_9999 })
    );

    for cut in [0, 10, HEADER_LEN as usize - 1, HEADER_LEN as usize, good.len() - 4, good.len() - 1] {
        assert_eq!(verify_bytes(&good[..cut], &t), Err(ImageError::Truncated), "cut at {cut}");
    }
    let mut longer = good.clone();
    longer.extend_from_slice(&[0; 4]);
    assert_eq!(verify_bytes(&longer, &t), Err(ImageError::TrailingData));

    let oversized = image(MAX_PAYLOAD_LEN as usize + 4, 0x0200_0000);
    assert_eq!(
        verify_bytes(&oversized, &t),
        Err(ImageError::Oversized { len: MAX_PAYLOAD_LEN + 4, max: MAX_PAYLOAD_LEN })
    );
    // The largest payload that fits is accepted.
    assert!(verify_bytes(&image(MAX_PAYLOAD_LEN as usize, 0x0200_0000), &t).is_ok());

    let mut magic = good.clone();
    magic[0] = b'X';
    assert_eq!(verify_bytes(&magic, &t), Err(ImageError::BadMagic));
    let mut version = good;
    version[4] = 9;
    assert_eq!(verify_bytes(&version, &t), Err(ImageError::UnsupportedVersion(9)));
}

/// Streams `img` into slot B in `chunk`-byte pieces; returns the first error (or `finish`'s result).
fn stream(img: &[u8], chunk: usize) -> Result<ImageHeader, UpdateError> {
    let mut b = SimFlash::new(SLOT_SECTOR, 4, 4);
    let mut s = SimFlash::new(STATE_SECTOR, 1, 4);
    let mut d = Download::new();
    d.clear(&mut b, &mut s, None)?;
    for (i, c) in img.chunks(chunk).enumerate() {
        d.write(&mut b, (i * chunk) as u32, c, &trust())?;
    }
    let mut buf = vec![0u8; 1024];
    d.finish(&mut b, &trust(), &mut buf)
}

#[test]
fn every_refusal_through_a_download_is_typed_and_wrong_headers_are_refused_before_the_payload() {
    let good = image(LEN, 0x0300_0000);
    // SDO segments carry 7 bytes, FoE packets some hundred: odd sizes must work.
    for chunk in [7, 128, 1000, LEN + 128] {
        assert_eq!(stream(&good, chunk).map(|h| h.payload_len), Ok(LEN as u32), "chunk {chunk}");
    }
    let mut bad_crc = good.clone();
    bad_crc[HEADER_LEN as usize + 5] ^= 0x10;
    assert!(matches!(stream(&bad_crc, 7), Err(UpdateError::Image(ImageError::Crc { .. }))));
    let other_key = image_signed_with(LEN, 0x0300_0000, HARDWARE_ID, &[0x42; 32]);
    assert_eq!(stream(&other_key, 1000), Err(UpdateError::Image(ImageError::BadSignature)));
    assert_eq!(stream(&good[..good.len() - 8], 1000), Err(UpdateError::Image(ImageError::Truncated)));
    assert_eq!(stream(&good[..100], 1000), Err(UpdateError::Image(ImageError::Truncated)));
    let mut longer = good.clone();
    longer.extend_from_slice(&[0; 8]);
    assert_eq!(stream(&longer, 1000), Err(UpdateError::Image(ImageError::TrailingData)));

    // A wrong hardware id or an oversized length is refused when the header is complete, before any payload.
    let other_hw = image_signed_with(LEN, 0x0300_0000, 0x1234_5678, &dev_seed());
    let mut b = SimFlash::new(SLOT_SECTOR, 4, 4);
    let mut s = SimFlash::new(STATE_SECTOR, 1, 4);
    let mut d = Download::new();
    d.clear(&mut b, &mut s, None).unwrap();
    let e = d.write(&mut b, 0, &other_hw[..HEADER_LEN as usize], &trust());
    assert_eq!(e, Err(UpdateError::Image(ImageError::WrongHardware { expected: HARDWARE_ID, found: 0x1234_5678 })));
    assert!(matches!(d.phase(), Phase::Failed(ImageError::WrongHardware { .. })));
    assert_eq!(d.write(&mut b, HEADER_LEN, &other_hw[128..256], &trust()), Err(UpdateError::Sequence));

    let oversized = image(MAX_PAYLOAD_LEN as usize + 4, 0x0300_0000);
    d.clear(&mut b, &mut s, None).unwrap();
    assert_eq!(
        d.write(&mut b, 0, &oversized[..HEADER_LEN as usize], &trust()),
        Err(UpdateError::Image(ImageError::Oversized { len: MAX_PAYLOAD_LEN + 4, max: MAX_PAYLOAD_LEN }))
    );
    // A stream longer than a slot is refused by its length alone, whatever its header says.
    d.clear(&mut b, &mut s, None).unwrap();
    let long = vec![0u8; 400 * 1024];
    assert!(matches!(d.write(&mut b, 0, &long, &trust()), Err(UpdateError::Image(ImageError::Oversized { .. }))));
}

#[test]
fn a_download_outside_the_clear_write_finish_activate_sequence_is_refused() {
    let img = image(LEN, 0x0400_0000);
    let mut b = SimFlash::new(SLOT_SECTOR, 4, 4);
    let mut s = SimFlash::new(STATE_SECTOR, 1, 4);
    let mut d = Download::new();
    let mut buf = vec![0u8; 256];
    assert_eq!(d.write(&mut b, 0, &img[..64], &trust()), Err(UpdateError::Sequence), "write without clear");
    assert_eq!(d.finish(&mut b, &trust(), &mut buf), Err(UpdateError::Sequence));
    assert_eq!(d.activate(&mut s), Err(UpdateError::Sequence), "activate without a verified image");
    d.clear(&mut b, &mut s, None).unwrap();
    assert_eq!(d.write(&mut b, 64, &img[64..128], &trust()), Err(UpdateError::OutOfOrder { expected: 0 }));
    d.write(&mut b, 0, &img[..64], &trust()).unwrap();
    assert_eq!(d.write(&mut b, 100, &img[100..200], &trust()), Err(UpdateError::OutOfOrder { expected: 64 }));
    d.abort();
    assert_eq!(d.write(&mut b, 64, &img[64..128], &trust()), Err(UpdateError::Sequence), "abort needs a new clear");
    // Slot B is erased by clear, so a second download over a first one works.
    for _ in 0..2 {
        d.clear(&mut b, &mut s, None).unwrap();
        d.write(&mut b, 0, &img, &trust()).unwrap();
        d.finish(&mut b, &trust(), &mut buf).unwrap();
    }
    assert_eq!(b.read(0, &mut [0u8; 4]), Ok(()));
}
