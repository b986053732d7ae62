use super::*;
use flowgate_protocol::motor::FaultBits;

#[test]
fn fault_bits_are_named() {
    assert_eq!(fault_names(FaultBits::default()), "none");
    assert_eq!(fault_names(FaultBits(FaultBits::DRIVER | FaultBits::ESTOP)), "e-stop, driver");
}

#[test]
fn a_thin_or_faulty_stream_fails() {
    assert_eq!(stream_verdict(35, 35.3, 0, 0), Verdict::Pass);
    assert_eq!(stream_verdict(35, 35.3, 0, 2), Verdict::Warn);
    assert_eq!(stream_verdict(27, 35.3, 0, 0), Verdict::Fail, "under 80% of the frames");
    assert_eq!(stream_verdict(0, 35.3, 0, 0), Verdict::Fail, "a silent stream");
    assert_eq!(stream_verdict(35, 35.3, 1, 0), Verdict::Fail, "a controller fault");
}

#[test]
fn the_table_counts_failures() {
    let mut r = CheckReport::default();
    r.pass(CONFIG, "rig.toml", "ok");
    r.fail(SERIAL, "/dev/x", "missing");
    r.skip(&[ANSWERS], "/dev/x", "the serial port failed");
    assert_eq!(r.failures(), 1);
    let text = r.to_string();
    assert!(text.contains("FAIL  serial port"), "{text}");
    assert!(text.ends_with("1 of 3 checks failed (0 warnings): fix them before arming"), "{text}");
}
