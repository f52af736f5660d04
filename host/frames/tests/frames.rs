//! The frame contract over real iceoryx2 shared memory: every test uses its own
//! camera id, so tests running in parallel never share a service.

use std::time::{Duration, Instant};

use fpm_frames::{FrameError, FrameHeader, FramePublisher, FrameSubscriber, ServiceNames};

fn unique(tag: &str) -> ServiceNames {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    ServiceNames::for_camera(&format!("test-{tag}-{}-{nanos}", std::process::id()))
}

fn header(n: u64, w: u32, h: u32) -> FrameHeader {
    FrameHeader {
        frame_number: n,
        timestamp_ns: 1_000 + n,
        exposure_us: 250,
        width: w,
        height: h,
        bit_depth: 12,
        camera_id: 3,
        ..FrameHeader::default()
    }
}

fn pattern(n: u64, len: usize) -> Vec<u16> {
    (0..len)
        .map(|i| ((i as u64 * 7 + n * 13) % 4096) as u16)
        .collect()
}

#[test]
fn frames_arrive_intact_in_order_and_wake_a_sleeping_subscriber() {
    let names = unique("roundtrip");
    let subscriber = FrameSubscriber::create(&names).unwrap();
    // iceoryx2's ipc ports stay on the thread that made them: the camera is a thread
    // with its own node, as it would be its own process.
    let camera_names = names.clone();
    let sender = std::thread::spawn(move || {
        let publisher = FramePublisher::create(&camera_names, 64 * 48).unwrap();
        std::thread::sleep(Duration::from_millis(100));
        for n in 0..3u64 {
            assert_eq!(
                publisher
                    .publish(header(n, 64, 48), &pattern(n, 64 * 48))
                    .unwrap(),
                1
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    let start = Instant::now();
    for n in 0..3u64 {
        let frame = subscriber
            .next(Duration::from_secs(5))
            .unwrap()
            .expect("a frame within 5 s");
        assert_eq!(
            *frame.header(),
            FrameHeader {
                pixel_count: 64 * 48,
                ..header(n, 64, 48)
            }
        );
        assert_eq!(frame.pixels(), &pattern(n, 64 * 48)[..]);
    }
    // The subscriber slept through the first 100 ms and woke for the frames.
    assert!(start.elapsed() < Duration::from_secs(2));
    sender.join().unwrap();
    // Nothing more: a timeout, not an error.
    let t = Instant::now();
    assert!(subscriber
        .next(Duration::from_millis(50))
        .unwrap()
        .is_none());
    assert!(t.elapsed() >= Duration::from_millis(50));
}

#[test]
fn a_loaned_buffer_is_filled_in_place() {
    let names = unique("loan");
    let subscriber = FrameSubscriber::create(&names).unwrap();
    let publisher = FramePublisher::create(&names, 1 << 16).unwrap();
    let mut loan = publisher.loan(header(9, 256, 256)).unwrap();
    assert!(
        loan.pixels_mut().iter().all(|&v| v == 0),
        "loans start zeroed"
    );
    loan.pixels_mut().copy_from_slice(&pattern(9, 256 * 256));
    loan.header_mut().timestamp_ns = 42;
    loan.send().unwrap();
    let frame = subscriber.next(Duration::from_secs(5)).unwrap().unwrap();
    assert_eq!(frame.header().timestamp_ns, 42);
    assert_eq!(frame.header().pixel_count, 65536);
    assert_eq!(frame.pixels(), &pattern(9, 256 * 256)[..]);
}

#[test]
fn bad_frames_are_refused_naming_the_field_and_never_sent() {
    let names = unique("bad");
    let subscriber = FrameSubscriber::create(&names).unwrap();
    let publisher = FramePublisher::create(&names, 100).unwrap();
    let err = publisher.publish(header(0, 10, 9), &[0; 100]).unwrap_err();
    assert!(err.to_string().contains("pixel_count"), "{err}");
    let err = publisher
        .publish(
            FrameHeader {
                bit_depth: 17,
                ..header(1, 10, 10)
            },
            &[0; 100],
        )
        .unwrap_err();
    assert!(err.to_string().contains("bit_depth"), "{err}");
    let err = publisher.loan(header(2, 20, 20)).err().unwrap();
    assert!(
        matches!(
            err,
            FrameError::TooLarge {
                pixels: 400,
                max: 100
            }
        ),
        "{err}"
    );
    assert!(subscriber
        .next(Duration::from_millis(50))
        .unwrap()
        .is_none());
}

#[test]
fn a_slow_consumer_loses_the_oldest_frames_and_sees_the_gap() {
    let names = unique("slow");
    let subscriber = FrameSubscriber::create(&names).unwrap();
    let publisher = FramePublisher::create(&names, 16).unwrap();
    for n in 0..6u64 {
        publisher.publish(header(n, 4, 4), &pattern(n, 16)).unwrap();
    }
    // The camera never blocked; the buffer kept the newest frames.
    let mut seen = vec![];
    while let Some(f) = subscriber.next(Duration::from_millis(50)).unwrap() {
        assert_eq!(f.pixels(), &pattern(f.header().frame_number, 16)[..]);
        seen.push(f.header().frame_number);
    }
    assert!(!seen.is_empty() && seen.len() < 6, "{seen:?}");
    assert_eq!(
        *seen.last().unwrap(),
        5,
        "the newest frame survives: {seen:?}"
    );
    assert!(seen[0] > 0, "the gap is visible in frame_number: {seen:?}");
}

/// A camera's settings reach an acquisition that starts after the camera (history of
/// one), and a camera that publishes none reads as None, quickly.
#[test]
fn camera_settings_reach_a_late_reader() {
    let names = unique("settings");
    let json = r#"{"pixel_format":"Mono12Packed","binning":[2,2]}"#;
    let camera = fpm_frames::SettingsPublisher::create(&names, json).unwrap();
    let reader = {
        let names = names.clone();
        std::thread::spawn(move || fpm_frames::read_settings(&names, Duration::from_secs(2)))
    };
    while !reader.is_finished() {
        camera.serve();
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(reader.join().unwrap().as_deref(), Some(json));
    let silent = unique("no-settings");
    let started = Instant::now();
    assert_eq!(
        fpm_frames::read_settings(&silent, Duration::from_millis(100)),
        None
    );
    assert!(started.elapsed() < Duration::from_secs(1));
}

/// Waits shorter than a µs come back (iceoryx2 takes a wait as a socket timeout in
/// whole µs, where 0 is forever: `fpm acquire` once hung at the end of a capture whose
/// frame thread met its deadline a few hundred ns early). Each call must return within
/// its timeout and a few ms; a hang fails the test instead of stalling it.
#[test]
fn a_wait_of_a_few_nanoseconds_returns() {
    let names = unique("tiny-wait");
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    // The subscriber's ports stay on the thread that made them.
    std::thread::spawn(move || {
        let subscriber = FrameSubscriber::create(&names).unwrap();
        // Timeouts a little longer than a look at the buffer takes, finely spread, so
        // that some calls are left with under a µs to wait.
        for nanos in (0..800u64).map(|k| 500 + (k * 37) % 6_000) {
            assert!(subscriber
                .next(Duration::from_nanos(nanos))
                .unwrap()
                .is_none());
        }
        let _ = done_tx.send(());
    });
    assert!(
        done_rx.recv_timeout(Duration::from_secs(20)).is_ok(),
        "a wait of under a µs did not come back"
    );
}
