use super::*;

/// Wire times: 33 bytes x 10 bits at 921600 baud; a CAN 2.0A frame with 7 data bytes is
/// 103 bits unstuffed; the SLCAN line `t1017` + 14 hex + CR is 20 bytes.
#[test]
fn wire_times() {
    let w = Wire::new();
    assert!((w.sample_frame_us - 330.0 / 0.9216).abs() < 1e-9);
    assert!((w.command_frame_us - 103.0).abs() < 1e-9);
    assert!((w.command_slcan_us - 200.0 / 0.9216).abs() < 1e-9);
    // Two RPDO1s of 6 data bytes: 95 bits each on CAN, `t2016` + 12 hex + CR as SLCAN.
    assert!((w.cia402_frames_us - 190.0).abs() < 1e-9);
    assert!((w.cia402_slcan_us - 360.0 / 0.9216).abs() < 1e-9);
    // Two 33-byte samples and a 21-byte frame end (13-byte payload, protocol/README.md).
    assert!((w.psd_frame_us - 870.0 / 0.9216).abs() < 1e-9);
    assert!((w.psd_max_samples_per_s - 2.0 * 92_160.0 / 87.0).abs() < 1e-6);
}
