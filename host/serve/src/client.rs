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
