//! A minimal blocking client of the service's API: HTTP/1.1 over TCP, one request per
//! connection, the body read to the end (as a script's `urllib` does). The tests, `fpm
//! bench serve` and `fpm demo --serve` drive the service with it; every failure is an error
//! naming the request.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// A response: status, headers (names lower-cased) and body (as bytes, and as text).
#[derive(Debug)]
pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub bytes: Vec<u8>,
    pub body: String,
}

impl Response {
    /// The value of header `name` (lower case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    /// The body as JSON.
    pub fn json(&self) -> anyhow::Result<serde_json::Value> {
        serde_json::from_str(&self.body).map_err(|e| {
            anyhow::anyhow!("the service's answer is not JSON ({e}): {:.200}", self.body)
        })
    }
}

/// `method path` on `address`, with these extra header lines (a `Host` among them
/// replaces the address) and `body` (JSON).
pub fn send(
    address: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Option<&str>,
) -> anyhow::Result<Response> {
    use anyhow::Context;
    let what = || format!("{method} http://{address}{path}");
    let mut stream = TcpStream::connect(address).with_context(what)?;
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .with_context(what)?;
    let mut text = format!("{method} {path} HTTP/1.1\r\nConnection: close\r\n");
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        text.push_str(&format!("Host: {address}\r\n"));
    }
    for (k, v) in headers {
        text.push_str(&format!("{k}: {v}\r\n"));
    }
    if let Some(b) = body {
        text.push_str(&format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            b.len()
        ));
    }
    text.push_str("\r\n");
    if let Some(b) = body {
        text.push_str(b);
    }
    stream.write_all(text.as_bytes()).with_context(what)?;
    let mut reader = BufReader::new(stream);
    let mut status_line = String::new();
    reader.read_line(&mut status_line).with_context(what)?;
    let status = status_line
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .with_context(|| format!("{}: not an HTTP status line: {status_line:?}", what()))?;
    let mut headers = vec![];
    loop {
        let mut line = String::new();
        reader.read_line(&mut line).with_context(what)?;
        if line.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            headers.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
        }
    }
    let chunked = headers
        .iter()
        .any(|(k, v)| k == "transfer-encoding" && v.eq_ignore_ascii_case("chunked"));
    let mut raw = Vec::new();
    reader.read_to_end(&mut raw).with_context(what)?;
    let body = if chunked { dechunk(&raw) } else { raw };
    Ok(Response {
        status,
        headers,
        body: String::from_utf8_lossy(&body).into_owned(),
        bytes: body,
    })
}

/// A chunked body's data (a malformed one is cut where it breaks).
fn dechunk(mut raw: &[u8]) -> Vec<u8> {
    let mut out = vec![];
    while let Some(end) = raw.windows(2).position(|w| w == b"\r\n") {
        let size =
            usize::from_str_radix(String::from_utf8_lossy(&raw[..end]).trim(), 16).unwrap_or(0);
        let Some(chunk) = raw.get(end + 2..end + 2 + size).filter(|_| size > 0) else {
            break;
        };
        out.extend_from_slice(chunk);
        raw = raw.get(end + 2 + size + 2..).unwrap_or_default();
    }
    out
}

/// `GET /api/events` as lines, as they come (the stream ends when the caller stops
/// reading or the service goes).
pub fn event_lines(
    address: SocketAddr,
    token: Option<&str>,
) -> anyhow::Result<impl Iterator<Item = String>> {
    use anyhow::Context;
    let mut stream = TcpStream::connect(address).context("GET /api/events")?;
    stream.set_read_timeout(Some(Duration::from_secs(60)))?;
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    write!(
        stream,
        "GET /api/events HTTP/1.1\r\nHost: {address}\r\nAccept: text/event-stream\r\n{auth}\r\n"
    )?;
    Ok(BufReader::new(stream).lines().map_while(Result::ok))
}

/// `fpm serve --virtual` started as a child process by a tool or test that wants a
/// service of its own (on 127.0.0.1, a free port, a virtual `size`² camera); stopped
/// with SIGTERM on drop, as a user's Ctrl-C would.
pub struct VirtualService {
    child: std::process::Child,
    /// Where it listens.
    pub address: SocketAddr,
    /// The token requests that change the rig carry.
    pub token: String,
    /// The page's address with the token, as the service printed it.
    pub page: String,
    /// Killed and reaped already: nothing to stop on drop.
    reaped: bool,
}

impl VirtualService {
    /// Start the executable `fpm` as `fpm serve --virtual` with its state in `state`,
    /// its log to `stderr`; returns once it listens.
    pub fn start(
        fpm: &std::path::Path,
        state: &std::path::Path,
        size: usize,
        stderr: std::process::Stdio,
    ) -> anyhow::Result<Self> {
        Self::start_with(fpm, state, &["--virtual-size", &size.to_string()], stderr)
    }

    /// [`VirtualService::start`] with `fpm serve`'s flags `args` (`--virtual-size`,
    /// `--virtual-slide-um`, …).
    pub fn start_with(
        fpm: &std::path::Path,
        state: &std::path::Path,
        args: &[&str],
        stderr: std::process::Stdio,
    ) -> anyhow::Result<Self> {
        let mut all = vec!["--virtual"];
        all.extend_from_slice(args);
        Self::start_serve(fpm, state, &all, stderr)
    }

    /// `fpm serve` on a rig of the caller's (`--port`, `--frames`, `--stage` in
    /// `args`), not a virtual one: nothing is started beside it.
    pub fn start_on_rig(
        fpm: &std::path::Path,
        state: &std::path::Path,
        args: &[&str],
        stderr: std::process::Stdio,
    ) -> anyhow::Result<Self> {
        Self::start_serve(fpm, state, args, stderr)
    }

    fn start_serve(
        fpm: &std::path::Path,
        state: &std::path::Path,
        args: &[&str],
        stderr: std::process::Stdio,
    ) -> anyhow::Result<Self> {
        use anyhow::Context;
        let mut child = std::process::Command::new(fpm)
            .args(["serve", "--listen", "127.0.0.1:0"])
            .args(args)
            .arg("--state-dir")
            .arg(state)
            .stdout(std::process::Stdio::piped())
            .stderr(stderr)
            .spawn()
            .context("starting fpm serve")?;
        let said: std::io::Result<Vec<String>> = child
            .stdout
            .take()
            .map(|out| BufReader::new(out).lines().take(3).collect())
            .unwrap_or_else(|| Ok(vec![]));
        let started = said.map_err(anyhow::Error::from).and_then(|lines| {
            let field = |prefix: &str| {
                lines
                    .iter()
                    .find_map(|l| l.strip_prefix(prefix))
                    .map(str::to_string)
                    .with_context(|| format!("fpm serve did not say {prefix:?}: {lines:?}"))
            };
            let address = field("fpm serve: listening on http://")?.parse()?;
            let page = field("the page: ")?;
            let token = std::fs::read_to_string(state.join("token"))
                .with_context(|| format!("reading {}", state.join("token").display()))?;
            Ok((address, page, token.trim().to_string()))
        });
        match started {
            Ok((address, page, token)) => Ok(Self {
                child,
                address,
                token,
                page,
                reaped: false,
            }),
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                Err(e)
            }
        }
    }

    /// `GET path`.
    pub fn get(&self, path: &str) -> anyhow::Result<Response> {
        send(self.address, "GET", path, &[], None)
    }

    /// `POST path` with the token and `body`.
    pub fn post(&self, path: &str, body: Option<&str>) -> anyhow::Result<Response> {
        let auth = format!("Bearer {}", self.token);
        send(
            self.address,
            "POST",
            path,
            &[("Authorization", &auth)],
            body,
        )
    }

    /// Queue `request`; its job id.
    pub fn submit(&self, request: &serde_json::Value) -> anyhow::Result<i64> {
        let r = self.post("/api/jobs", Some(&request.to_string()))?;
        if r.status != 202 {
            anyhow::bail!("the service refused the job ({}): {}", r.status, r.body);
        }
        r.json()?["id"]
            .as_i64()
            .ok_or_else(|| anyhow::anyhow!("no job id in {}", r.body))
    }

    /// Job `id` once it has ended (an error if not within `timeout`).
    pub fn wait(&self, id: i64, timeout: Duration) -> anyhow::Result<serde_json::Value> {
        let start = std::time::Instant::now();
        loop {
            let job = self.get(&format!("/api/jobs/{id}"))?.json()?;
            if !matches!(job["state"].as_str(), Some("queued" | "running")) {
                return Ok(job);
            }
            if start.elapsed() > timeout {
                anyhow::bail!("job {id} still {} after {timeout:?}", job["state"]);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGKILL, as a crash or the OOM killer would.
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.reaped = true;
    }

    /// Stop it as Ctrl-C would (SIGTERM) and wait for it to exit, at most `within`
    /// (then it is killed, and that is the error).
    pub fn stop(mut self, within: std::time::Duration) -> anyhow::Result<std::process::ExitStatus> {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = std::time::Instant::now() + within;
        self.reaped = true;
        loop {
            if let Some(status) = self.child.try_wait()? {
                return Ok(status);
            }
            if std::time::Instant::now() > deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                anyhow::bail!("fpm serve did not stop within {within:?} of SIGTERM; killed");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Whether it is still running.
    pub fn running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }
}

impl Drop for VirtualService {
    fn drop(&mut self) {
        if self.reaped {
            return;
        }
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let _ = self.child.wait();
    }
}
