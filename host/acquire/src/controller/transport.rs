//! postcard-rpc's host client over a `serialport` byte stream with COBS framing.
//!
//! A reader thread owns the receive side and hands complete frames to the client's
//! async worker; the transmit side writes whole encoded frames. A read error (the
//! device unplugged, the emulator killed) ends the reader, which closes the client, so
//! every pending and later request fails at once instead of waiting for its timeout.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use fpm_firmware::link::{Feed, FrameReceiver};
use postcard_rpc::host_client::{WireRx, WireSpawn, WireTx};
use serialport::SerialPort;
use tokio::sync::mpsc;

/// Why the link closed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// Writing to the port failed.
    #[error("write failed: {0}")]
    Write(#[from] std::io::Error),
    /// The reader ended (port closed or failed).
    #[error("the serial port closed")]
    Closed,
}

pub struct SerialTx {
    port: Arc<Mutex<Box<dyn SerialPort>>>,
}

impl WireTx for SerialTx {
    type Error = LinkError;

    async fn send(&mut self, data: Vec<u8>) -> Result<(), LinkError> {
        let mut wire = vec![0u8; data.len() + data.len() / 254 + 2];
        let used = fpm_firmware::link::encode(&data, &mut wire)
            .map(<[u8]>::len)
            .ok_or(LinkError::Closed)?;
        let mut port = self.port.lock().map_err(|_| LinkError::Closed)?;
        // No flush: on a tty it is tcdrain(), which waits for the device to read.
        port.write_all(&wire[..used])?;
        Ok(())
    }
}

pub struct SerialRx {
    frames: mpsc::UnboundedReceiver<Vec<u8>>,
}

impl WireRx for SerialRx {
    type Error = LinkError;

    async fn receive(&mut self) -> Result<Vec<u8>, LinkError> {
        self.frames.recv().await.ok_or(LinkError::Closed)
    }
}

/// Spawns the client's workers on a tokio runtime.
pub struct Spawner(pub tokio::runtime::Handle);

impl WireSpawn for Spawner {
    fn spawn(&mut self, fut: impl std::future::Future<Output = ()> + Send + 'static) {
        drop(self.0.spawn(fut));
    }
}

/// The reader thread; stopping it (on drop) releases the port at once, so the next
/// program can open it.
pub struct Reader {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Split an open port into the client's transmit and receive halves and the thread
/// that feeds the receive half.
pub fn split(
    port: Box<dyn SerialPort>,
    port_name: String,
) -> std::io::Result<(SerialTx, SerialRx, Reader)> {
    let mut reader = port.try_clone().map_err(std::io::Error::other)?;
    reader
        .set_timeout(Duration::from_millis(20))
        .map_err(std::io::Error::other)?;
    let (tx, rx) = mpsc::unbounded_channel();
    let stop = Arc::new(AtomicBool::new(false));
    let stop_reader = stop.clone();
    let thread = std::thread::Builder::new()
        .name(format!("fpm-serial-rx {port_name}"))
        .spawn(move || read_loop(reader, tx, port_name, stop_reader))?;
    Ok((
        SerialTx {
            port: Arc::new(Mutex::new(port)),
        },
        SerialRx { frames: rx },
        Reader {
            stop,
            thread: Some(thread),
        },
    ))
}

fn read_loop(
    mut port: Box<dyn SerialPort>,
    frames: mpsc::UnboundedSender<Vec<u8>>,
    name: String,
    stop: Arc<AtomicBool>,
) {
    let mut receiver = Box::new(FrameReceiver::new());
    let mut buf = [0u8; 1024];
    loop {
        if frames.is_closed() || stop.load(Ordering::SeqCst) {
            return;
        }
        match port.read(&mut buf) {
            Ok(0) => {
                tracing::warn!("{name}: end of stream");
                return;
            }
            Ok(n) => {
                for &b in &buf[..n] {
                    match receiver.feed(b) {
                        Feed::Pending => {}
                        Feed::Frame(f) => {
                            if frames.send(f.to_vec()).is_err() {
                                return;
                            }
                        }
                        Feed::Dropped => {
                            tracing::warn!("{name}: dropped a malformed frame from the device")
                        }
                    }
                }
            }
            Err(e)
                if e.kind() == std::io::ErrorKind::TimedOut
                    || e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => {
                tracing::debug!("{name}: read failed: {e}");
                return;
            }
        }
    }
}
