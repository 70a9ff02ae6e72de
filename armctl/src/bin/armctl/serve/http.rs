//! The little HTTP/1.1 the pendant needs, on std's TCP: requests one after another on a
//! kept-alive connection (no pipelining: browsers do not), a parsed request line, query and
//! body, and responses, among them a server-sent event stream. Keeping connections alive
//! keeps the e-stop's request off a new connection and a new thread. Parsing is sans-io ([`parse_head`]) and bounded: a request
//! too large or malformed gets a 4xx, never a panic.

use std::io::{Read, Write};
use std::time::Duration;

/// The longest request head (request line and headers) taken: a browser's are under 2 KiB.
pub const MAX_HEAD: usize = 8 * 1024;

/// The largest body taken: a trajectory file uploaded from the page (the controller takes
/// at most [`armctl::MAX_POINTS`] points; a CSV line per point of 8 joints is under 100
/// bytes, so 4 MiB is ample).
pub const MAX_BODY: usize = 4 * 1024 * 1024;

/// How long a client may take to send its request, or keep an idle connection, before the
/// connection is dropped.
pub const READ_TIMEOUT: Duration = Duration::from_secs(10);

/// A request: method, path, query parameters (decoded) and body.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Request {
    pub method: String,
    pub path: String,
    pub query: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Request {
    /// The query parameter `name`, if given.
    pub fn param(&self, name: &str) -> Option<&str> {
        self.query
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
}

/// Why a request was not taken; each is answered with its status line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HttpError {
    /// Not HTTP, or a request line without method and path (400).
    Malformed,
    /// The head is longer than [`MAX_HEAD`] (431).
    HeadTooLarge,
    /// The body is longer than [`MAX_BODY`] (413).
    BodyTooLarge,
    /// The connection ended (or idled out) before a request began: nothing to answer.
    Closed,
}

impl HttpError {
    /// The response's status line.
    pub fn status(self) -> &'static str {
        match self {
            HttpError::Malformed => "400 Bad Request",
            HttpError::HeadTooLarge => "431 Request Header Fields Too Large",
            HttpError::BodyTooLarge => "413 Payload Too Large",
            HttpError::Closed => "400 Bad Request",
        }
    }
}

/// The request head in `head` (without the blank line): the request and the body length it
/// announces.
pub fn parse_head(head: &str) -> Result<(Request, usize), HttpError> {
    let mut lines = head.split("\r\n");
    let mut words = lines.next().unwrap_or("").split(' ');
    let (Some(method), Some(target), Some(version)) = (words.next(), words.next(), words.next())
    else {
        return Err(HttpError::Malformed);
    };
    if !version.starts_with("HTTP/1.") || method.is_empty() || !target.starts_with('/') {
        return Err(HttpError::Malformed);
    }
    let mut length = 0usize;
    for line in lines {
        let Some((name, value)) = line.split_once(':') else {
            continue;
        };
        if name.trim().eq_ignore_ascii_case("content-length") {
            length = value.trim().parse().map_err(|_| HttpError::Malformed)?;
        }
    }
    if length > MAX_BODY {
        return Err(HttpError::BodyTooLarge);
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    let query = query
        .split('&')
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (k, v) = p.split_once('=').unwrap_or((p, ""));
            (percent_decode(k), percent_decode(v))
        })
        .collect();
    Ok((
        Request {
            method: method.to_string(),
            path: percent_decode(path),
            query,
            body: Vec::new(),
        },
        length,
    ))
}

/// `%XX` and `+` decoded; a malformed escape is kept as it is.
pub fn percent_decode(text: &str) -> String {
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < bytes.len() => match (hex(bytes[i + 1]), hex(bytes[i + 2])) {
                (Some(hi), Some(lo)) => {
                    out.push(hi << 4 | lo);
                    i += 2;
                }
                _ => out.push(b'%'),
            },
            b => out.push(b),
        }
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Reads one request from `stream`: the head (at most [`MAX_HEAD`]) and the body it
/// announces (at most [`MAX_BODY`]).
pub fn read_request(stream: &mut impl Read) -> Result<Request, HttpError> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 4096];
    let head_end = loop {
        if let Some(at) = find_blank_line(&buf) {
            break at;
        }
        if buf.len() > MAX_HEAD {
            return Err(HttpError::HeadTooLarge);
        }
        match stream.read(&mut chunk) {
            Ok(0) | Err(_) if buf.is_empty() => return Err(HttpError::Closed),
            Ok(0) | Err(_) => return Err(HttpError::Malformed),
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
        }
    };
    if head_end > MAX_HEAD {
        return Err(HttpError::HeadTooLarge);
    }
    let head = std::str::from_utf8(&buf[..head_end]).map_err(|_| HttpError::Malformed)?;
    let (mut request, length) = parse_head(head)?;
    let mut body = buf.split_off(head_end + 4);
    while body.len() < length {
        match stream.read(&mut chunk) {
            Ok(0) | Err(_) => return Err(HttpError::Malformed),
            Ok(n) => body.extend_from_slice(&chunk[..n]),
        }
    }
    body.truncate(length);
    request.body = body;
    Ok(request)
}

fn hex(digit: u8) -> Option<u8> {
    char::from(digit)
        .to_digit(16)
        .and_then(|d| u8::try_from(d).ok())
}

fn find_blank_line(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n")
}

/// Writes a whole response; the connection stays open for the next request.
pub fn respond(
    stream: &mut impl Write,
    status: &str,
    content_type: &str,
    body: &[u8],
) -> std::io::Result<()> {
    write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n\
         Cache-Control: no-store\r\nConnection: keep-alive\r\n\r\n",
        body.len()
    )?;
    stream.write_all(body)?;
    stream.flush()
}

/// A JSON response.
pub fn respond_json(
    stream: &mut impl Write,
    status: &str,
    value: &serde_json::Value,
) -> std::io::Result<()> {
    respond(
        stream,
        status,
        "application/json",
        value.to_string().as_bytes(),
    )
}

/// The head of a server-sent event stream; events follow with [`write_event`].
pub fn start_events(stream: &mut impl Write) -> std::io::Result<()> {
    stream.write_all(
        b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n\
          Connection: close\r\n\r\n",
    )?;
    stream.flush()
}

/// One server-sent event `name` carrying `data` (one line of JSON).
pub fn write_event(stream: &mut impl Write, name: &str, data: &str) -> std::io::Result<()> {
    write!(stream, "event: {name}\ndata: {data}\n\n")?;
    stream.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_with_query_and_body() {
        let raw = b"POST /api/jog?joint=2&by=-1.5&token=a%20b HTTP/1.1\r\nHost: x\r\n\
                    Content-Length: 5\r\n\r\nhello";
        let request = read_request(&mut &raw[..]).unwrap();
        assert_eq!(request.method, "POST");
        assert_eq!(request.path, "/api/jog");
        assert_eq!(request.param("joint"), Some("2"));
        assert_eq!(request.param("by"), Some("-1.5"));
        assert_eq!(request.param("token"), Some("a b"));
        assert_eq!(request.body, b"hello");
    }

    #[test]
    fn bad_requests_are_errors_not_panics() {
        assert_eq!(read_request(&mut &b""[..]), Err(HttpError::Closed));
        for raw in [
            &b"\r\n\r\n"[..],
            b"GET\r\n\r\n",
            b"GET nopath HTTP/1.1\r\n\r\n",
            b"GET / SPDY\r\n\r\n",
            b"POST / HTTP/1.1\r\nContent-Length: x\r\n\r\n",
            b"POST / HTTP/1.1\r\nContent-Length: 10\r\n\r\nshort",
            b"GET /%zz%4 HTTP/1.1",
            b"\xff\xfe / HTTP/1.1\r\n\r\n",
        ] {
            assert!(read_request(&mut &raw[..]).is_err(), "{raw:?}");
        }
        let big = format!(
            "POST / HTTP/1.1\r\nContent-Length: {}\r\n\r\n",
            MAX_BODY + 1
        );
        assert_eq!(
            read_request(&mut big.as_bytes()),
            Err(HttpError::BodyTooLarge)
        );
        let long = format!("GET /{} HTTP/1.1\r\n\r\n", "a".repeat(MAX_HEAD + 10));
        assert_eq!(
            read_request(&mut long.as_bytes()),
            Err(HttpError::HeadTooLarge)
        );
        assert_eq!(percent_decode("%zz%4"), "%zz%4");
        assert_eq!(percent_decode("a%2Fb+c"), "a/b c");
    }
}
