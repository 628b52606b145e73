//! The packet decoder on arbitrary bytes: it must never panic, and whatever it accepts
//! must encode back to exactly the same bytes (one encoding per packet).
#![no_main]

use libfuzzer_sys::fuzz_target;
use rotacal_shared::packet::{Packet, MAX_PACKET};

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = Packet::decode(data) {
        let mut buf = [0u8; MAX_PACKET];
        let n = p
            .encode(&mut buf)
            .expect("a decoded packet fits MAX_PACKET");
        assert_eq!(&buf[..n], data, "decode then encode changed the bytes");
    }
});
