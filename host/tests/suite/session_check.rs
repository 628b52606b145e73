//! The session check on the host's own run of the device logic (the QEMU run is compared
//! with it in scripts/test-all), and its refusal of damaged or incomplete logs.
use rotacal::verify::session::{check, host_packets, parse_log};

fn log_of(packets: &[Vec<u8>]) -> String {
    let mut s = String::from("booting\n");
    for p in packets {
        s.push_str("P ");
        for b in p {
            s.push_str(&format!("{b:02x}"));
        }
        s.push('\n');
    }
    s + "session done packets=0\n"
}

#[test]
fn the_hosts_run_passes_its_own_check() {
    let packets = host_packets();
    let parsed = parse_log(&log_of(&packets), "log").unwrap();
    assert_eq!(parsed, packets);
    let rep = check(&parsed).unwrap();
    assert!(rep.bit_identical_to_host && rep.seq_contiguous);
    assert_eq!(rep.samples, 12_597);
    assert_eq!(rep.fits.iter().filter(|f| f.is_final).count(), 3);
    assert!(rep.max_ratio_crlb <= 1e-5, "{}", rep.max_ratio_crlb);
    assert!(rep.quick_look_max_ratio_u.unwrap() <= 1e-4);
}

#[test]
fn damage_is_found() {
    let mut packets = host_packets();
    // One sum of counts changed in the tenth packet (a sample batch; byte 22 is the first
    // sample's sum of u): no longer the host's bytes, and the fit of its window no longer
    // matches the reported one exactly.
    let i = packets.iter().position(|p| p[1] == 0x01).unwrap() + 9;
    packets[i][22] ^= 0x40;
    // Changed on the way (its CRC no longer its bytes'): refused, naming the packet.
    let e = check(&packets).unwrap_err().to_string();
    assert!(e.contains("corrupted"), "{e}");
    // Changed by the device itself (the CRC made over the wrong sum): read, and found.
    let n = packets[i].len() - 2;
    let crc = rotacal_shared::packet::checksum(&packets[i][..n]);
    packets[i][n..].copy_from_slice(&crc.to_le_bytes());
    let rep = check(&packets).unwrap();
    assert!(!rep.bit_identical_to_host);
    assert_eq!(rep.first_difference, Some(i));
    assert!(rep.max_ratio_crlb > 1e-5, "{}", rep.max_ratio_crlb);
    // A lost packet breaks the sequence.
    let mut lost = host_packets();
    lost.remove(i);
    assert!(!check(&lost).unwrap().seq_contiguous);
}

#[test]
fn bad_logs_name_the_line() {
    let e = parse_log("P 0102\nP 01x\n", "s.log")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("s.log:2:"), "{e}");
    let e = parse_log("P 0102\n", "s.log").unwrap_err().to_string();
    assert!(e.contains("did not finish"), "{e}");
}
