//! Two nodes in one process (as two processes would be): lossless delivery in order, the
//! first-frame handshake, and the backpressure time limit.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use railmon_bus::{BusConfig, BusNode, DriveChannels, DriveFrame, FrameHeader};

/// Removes what iceoryx2 leaves of a private bus (per-prefix segment, root directory).
struct Cleanup(BusConfig);

impl Drop for Cleanup {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0.root_path);
        for segment in shm_segments(&self.0.prefix) {
            let _ = std::fs::remove_file(segment);
        }
    }
}

/// The files in /dev/shm (iceoryx2's segments) whose names start with `prefix`.
fn shm_segments(prefix: &str) -> Vec<std::path::PathBuf> {
    std::fs::read_dir("/dev/shm")
        .into_iter()
        .flatten()
        .flatten()
        .filter(|entry| entry.file_name().to_string_lossy().starts_with(prefix))
        .map(|entry| entry.path())
        .collect()
}

/// A bus of its own (tests run in parallel); keep the `Cleanup` until the nodes are gone.
fn private_bus(buffer: usize, backpressure_ms: u64) -> (BusConfig, Cleanup) {
    static N: AtomicUsize = AtomicUsize::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let prefix = format!("rmbt{}_{n}_", std::process::id());
    let mut config = BusConfig {
        root_path: format!("/tmp/railmon-test/{prefix}/"),
        prefix,
        ..BusConfig::default()
    };
    config.drive.subscriber_buffer_size = buffer;
    config.drive.backpressure_timeout_ms = backpressure_ms;
    (config.clone(), Cleanup(config))
}

fn frame(step: u64) -> DriveFrame {
    let drive = DriveChannels {
        u_alpha_v: step as f64,
        ..Default::default()
    };
    DriveFrame::new(125_000, &[drive; 3]).unwrap()
}

#[test]
fn lossless_stream_arrives_complete_and_in_order() {
    let (config, _cleanup) = private_bus(8, 2_000);
    let subscriber_node = BusNode::create(&config, "sub").unwrap();
    let subscriber = subscriber_node.subscriber::<DriveFrame>().unwrap();
    let total = 3_000u64;
    let publisher_config = config.clone();
    let sender = std::thread::spawn(move || {
        let node = BusNode::create(&publisher_config, "pub").unwrap();
        let mut publisher = node.publisher::<DriveFrame>().unwrap();
        publisher
            .wait_for_subscriber(Some(Duration::from_secs(5)), &|| false)
            .unwrap();
        for step in 0..total {
            assert_eq!(publisher.send(&frame(step), step * 125_000).unwrap(), 1);
            publisher.notify().unwrap();
        }
    });
    let waitset = subscriber_node.waitset().unwrap();
    let _guard = waitset.attach_notification(subscriber.listener()).unwrap();
    let mut headers: Vec<FrameHeader> = Vec::new();
    let start = Instant::now();
    while (headers.len() as u64) < total && start.elapsed() < Duration::from_secs(20) {
        waitset
            .wait_and_process_once_with_timeout(
                |_| iceoryx2::prelude::CallbackProgression::Continue,
                Duration::from_millis(50),
            )
            .unwrap();
        subscriber.take_wakeups().unwrap();
        subscriber
            .drain(usize::MAX, |received| {
                assert_eq!(
                    received.frame.drives[0].u_alpha_v,
                    received.header.sequence as f64
                );
                assert!(received.received_at_ns >= received.header.published_at_ns);
                headers.push(*received.header);
            })
            .unwrap();
    }
    sender.join().unwrap();
    assert_eq!(headers.len() as u64, total);
    for (i, h) in headers.iter().enumerate() {
        assert_eq!(h.sequence, i as u64);
        assert_eq!(h.sample_time_ns, i as u64 * 125_000);
        assert_eq!(h.publisher_instance, headers[0].publisher_instance);
    }
}

#[test]
fn a_subscriber_that_never_reads_delays_each_send_by_at_most_the_time_limit() {
    let (config, _cleanup) = private_bus(2, 20);
    let node = BusNode::create(&config, "both").unwrap();
    let stuck = node.subscriber::<DriveFrame>().unwrap();
    let mut publisher = node.publisher::<DriveFrame>().unwrap();
    publisher.notify().unwrap();
    stuck.attach().unwrap(); // connects, as the service does on its first wake-up
    let start = Instant::now();
    for step in 0..5 {
        publisher.send(&frame(step), 0).unwrap();
    }
    // 2 fit in the buffer, the other 3 each wait ~20 ms and are dropped.
    let elapsed = start.elapsed();
    assert!(elapsed >= Duration::from_millis(40), "{elapsed:?}");
    assert!(elapsed < Duration::from_millis(1_000), "{elapsed:?}");
}

#[test]
fn a_frame_resent_after_a_stall_arrives_under_its_own_number() {
    let (config, _cleanup) = private_bus(2, 20);
    let node = BusNode::create(&config, "both").unwrap();
    let slow = node.subscriber::<DriveFrame>().unwrap();
    let mut publisher = node.publisher::<DriveFrame>().unwrap();
    slow.attach().unwrap();
    assert_eq!(publisher.send(&frame(0), 0).unwrap(), 1);
    assert_eq!(publisher.send(&frame(1), 1).unwrap(), 1);
    // The buffer (2) is full and nobody reads for longer than the 20 ms limit: frame 2 is
    // dropped for the subscriber, and its number is used up.
    assert_eq!(publisher.send(&frame(2), 2).unwrap(), 0);
    assert_eq!(publisher.next_sequence(), 3);
    let mut sequences = Vec::new();
    let read = |sequences: &mut Vec<u64>| {
        slow.drain(usize::MAX, |r| {
            assert_eq!(r.frame.drives[0].u_alpha_v, r.header.sequence as f64);
            sequences.push(r.header.sequence)
        })
        .unwrap()
    };
    read(&mut sequences);
    // Once the subscriber reads again, the same frame goes under the same number: no gap.
    assert_eq!(publisher.resend(&frame(2), 2).unwrap(), 1);
    assert_eq!(publisher.send(&frame(3), 3).unwrap(), 1);
    read(&mut sequences);
    assert_eq!(sequences, [0, 1, 2, 3]);
}

#[test]
fn resending_before_any_send_is_an_error() {
    let (config, _cleanup) = private_bus(2, 20);
    let node = BusNode::create(&config, "early").unwrap();
    let mut publisher = node.publisher::<DriveFrame>().unwrap();
    let err = publisher.resend(&frame(0), 0).unwrap_err().to_string();
    assert!(err.contains("nothing was sent yet"), "{err}");
}

#[test]
fn waiting_for_a_subscriber_times_out_with_the_service_name() {
    let (config, _cleanup) = private_bus(2, 20);
    let node = BusNode::create(&config, "lonely").unwrap();
    let publisher = node.publisher::<DriveFrame>().unwrap();
    let err = publisher
        .wait_for_subscriber(Some(Duration::from_millis(30)), &|| false)
        .unwrap_err()
        .to_string();
    assert!(err.contains("railmon/drive"), "{err}");
}

/// Every file of the bus with `config`'s prefix and root path: (path, mode).
fn bus_files(config: &BusConfig) -> Vec<(String, u32)> {
    use std::os::unix::fs::PermissionsExt;
    fn walk(dir: &std::path::Path, out: &mut Vec<(String, u32)>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let meta = std::fs::symlink_metadata(entry.path()).unwrap();
            out.push((
                entry.path().display().to_string(),
                meta.permissions().mode() & 0o7777,
            ));
            if meta.is_dir() {
                walk(&entry.path(), out);
            }
        }
    }
    let mut files = Vec::new();
    walk(std::path::Path::new(&config.root_path), &mut files);
    for segment in shm_segments(&config.prefix) {
        let mode = std::fs::metadata(&segment).unwrap().permissions().mode() & 0o7777;
        files.push((segment.display().to_string(), mode));
    }
    files
}

/// Issue 11: iceoryx2 makes its global management segment 0666 and leaves it after the last
/// node; `BusNode::create` makes it 0600. No file of a service's or replay's bus (nodes,
/// publisher, subscriber, their services) may be writable by others, while running and after.
#[test]
fn no_file_of_the_bus_is_writable_by_others_while_running_or_after() {
    let (config, _cleanup) = private_bus(8, 2_000);
    {
        let subscriber_node = BusNode::create(&config, "sub").unwrap();
        let _subscriber = subscriber_node.subscriber::<DriveFrame>().unwrap();
        let publisher_node = BusNode::create(&config, "pub").unwrap();
        let mut publisher = publisher_node.publisher::<DriveFrame>().unwrap();
        publisher.send(&frame(0), 0).unwrap();
        let running = bus_files(&config);
        assert!(
            running
                .iter()
                .any(|(path, _)| path.ends_with(".global_mgmt")),
            "the management segment exists while nodes run: {running:?}"
        );
        let open: Vec<_> = running
            .iter()
            .filter(|(_, mode)| mode & 0o002 != 0)
            .collect();
        assert!(open.is_empty(), "world-writable while running: {open:?}");
    }
    let after = bus_files(&config);
    let open: Vec<_> = after.iter().filter(|(_, mode)| mode & 0o002 != 0).collect();
    assert!(
        open.is_empty(),
        "world-writable after the nodes ended: {open:?}"
    );
}
