//! Runs the shared self-test cases on the host (the same cases run under QEMU).
use rotacal_shared::selftest::CASES;

#[test]
fn shared_selftest_cases() {
    let mut failed = 0;
    for case in CASES {
        match (case.run)() {
            Ok(()) => println!("ok   {}", case.name),
            Err(what) => {
                println!("FAIL {}: {what}", case.name);
                failed += 1;
            }
        }
    }
    assert_eq!(failed, 0, "{failed} self-test case(s) failed");
}
