//! A serial port spoken in text lines, as every stage firmware here does.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use crate::StageError;

/// A serial port read as lines (`\n`-terminated, `\r` dropped) and written as bytes.
pub struct LinePort {
    port: Box<dyn serialport::SerialPort>,
    name: String,
    pending: Vec<u8>,
}

impl LinePort {
    /// Open `path` at `baud`, dropping whatever was waiting in its buffers.
    pub fn open(path: &str, baud: u32) -> Result<Self, StageError> {
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(20))
            .open()
            .map_err(|e| StageError::Open {
                port: path.into(),
                reason: e.to_string(),
            })?;
        let _ = port.clear(serialport::ClearBuffer::All);
        Ok(Self {
            port,
            name: path.into(),
            pending: Vec::new(),
        })
    }

    /// The port's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Send `bytes` as they are.
    pub fn send(&mut self, bytes: &[u8], during: &str) -> Result<(), StageError> {
        tracing::trace!(port = %self.name, sent = %String::from_utf8_lossy(bytes).trim_end(), "stage");
        self.port
            .write_all(bytes)
            .and_then(|_| self.port.flush())
            .map_err(|e| self.gone(during, e))
    }

    /// Send one line (a `\n` is added).
    pub fn send_line(&mut self, line: &str, during: &str) -> Result<(), StageError> {
        self.send(format!("{line}\n").as_bytes(), during)
    }

    /// The next non-empty line, or `None` if none came by `deadline`.
    pub fn read_line(
        &mut self,
        deadline: Instant,
        during: &str,
    ) -> Result<Option<String>, StageError> {
        loop {
            if let Some(i) = self.pending.iter().position(|&b| b == b'\n') {
                let raw: Vec<u8> = self.pending.drain(..=i).collect();
                let line = String::from_utf8_lossy(&raw).trim().to_string();
                if line.is_empty() {
                    continue;
                }
                tracing::trace!(port = %self.name, received = %line, "stage");
                return Ok(Some(line));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            let mut buf = [0u8; 256];
            match self.port.read(&mut buf) {
                Ok(0) => {
                    return Err(self.gone(
                        during,
                        std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "end of stream"),
                    ))
                }
                Ok(n) => self.pending.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(self.gone(during, e)),
            }
        }
    }

    /// Lines until one for which `done` says yes (returned), each other line given to
    /// `other` (which may fail the wait); times out at `deadline`.
    pub fn wait_for(
        &mut self,
        deadline: Instant,
        during: &str,
        mut done: impl FnMut(&str) -> bool,
        mut other: impl FnMut(&str) -> Result<(), StageError>,
    ) -> Result<String, StageError> {
        let started = Instant::now();
        loop {
            match self.read_line(deadline, during)? {
                Some(line) if done(&line) => return Ok(line),
                Some(line) => other(&line)?,
                None => {
                    return Err(StageError::Timeout {
                        port: self.name.clone(),
                        during: during.into(),
                        after: started.elapsed(),
                    })
                }
            }
        }
    }

    /// Drop whatever has arrived and is still unread.
    pub fn discard_input(&mut self) {
        self.pending.clear();
        let _ = self.port.clear(serialport::ClearBuffer::Input);
    }

    fn gone(&self, during: &str, e: std::io::Error) -> StageError {
        StageError::Disconnected {
            port: self.name.clone(),
            during: during.into(),
            reason: e.to_string(),
        }
    }
}
