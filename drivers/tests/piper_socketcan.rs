//! The SocketCAN backend on a real `vcan0`, when the kernel has one (`modprobe vcan; ip link
//! add vcan0 type vcan; ip link set vcan0 up`). CI kernels have no vcan (docs/protocols.md §4.5):
//! there the test prints a SKIPPED line and passes; the in-process bus tests in
//! easyhec-mocks cover the driver.

#[tokio::test]
async fn piper_frames_cross_vcan0() {
    #[cfg(not(feature = "socketcan"))]
    println!("SKIPPED piper_frames_cross_vcan0: built without the `socketcan` feature");
    #[cfg(feature = "socketcan")]
    {
        use easyhec_drivers::piper::frame::{joint_target_frames, ModeCommand};
        use easyhec_drivers::piper::{CanBus, SocketCan};
        use std::time::Duration;

        if !std::path::Path::new("/sys/class/net/vcan0").exists() {
            println!("SKIPPED piper_frames_cross_vcan0: no vcan0 interface on this machine");
            return;
        }
        let (a, b) = (SocketCan::new("vcan0"), SocketCan::new("vcan0"));
        // Open b's socket before a sends (a raw socket only sees frames sent after it opened).
        let first = b.recv();
        tokio::pin!(first);
        let _ = tokio::time::timeout(Duration::from_millis(50), &mut first).await;
        let mode = ModeCommand::move_j(30).encode();
        a.send(&mode).await.unwrap();
        let got = tokio::time::timeout(Duration::from_secs(1), first)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(got, mode);
        for f in joint_target_frames(&[10_000, -20_000, 0, 0, 0, 0]) {
            a.send(&f).await.unwrap();
            assert_eq!(b.recv().await.unwrap(), f);
        }
    }
}

/// A missing interface is a one-line connection error naming it, at first use (building the
/// backend touches nothing).
#[cfg(feature = "socketcan")]
#[tokio::test]
async fn a_missing_interface_is_a_connection_error() {
    use easyhec_drivers::piper::{CanBus, CanFrame, SocketCan};
    use easyhec_drivers::DriverError;
    let bus = SocketCan::new("nocan7");
    match bus.send(&CanFrame::full(0x151, [0; 8])).await {
        Err(DriverError::Connection(m)) => assert!(m.starts_with("CAN interface nocan7: "), "{m}"),
        other => panic!("{other:?}"),
    }
}
