//! A small blocking client of the stream server, for `envlight subscribe`, the examples and
//! the tests.
//!
//! [`Endpoint`] parses the address forms the command line accepts:
//! `unix:/run/envlight/envlight.sock` (or any path containing a `/`), `tcp:HOST:PORT` (or just
//! `HOST:PORT`) and `ws://HOST:PORT/`. [`Client::connect`] connects and subscribes;
//! [`Client::next_message`] returns the messages one by one.
//!
//! On Unix sockets and TCP the subscribe is sent in the binary form; frames then arrive binary
//! or as JSON lines, as requested. On WebSocket the subscribe is a text message for JSON frames
//! and a binary one for binary frames.

use super::protocol::{self, Decoder, Format, Message, ProtocolError, Request};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::time::Duration;
use tokio_tungstenite::tungstenite;

/// Where a server listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    Unix(PathBuf),
    Tcp(String),
    WebSocket(String),
}

impl std::str::FromStr for Endpoint {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(path) = s.strip_prefix("unix:") {
            if path.is_empty() {
                return Err(
                    "unix: needs a socket path, e.g. unix:/run/envlight/envlight.sock".into(),
                );
            }
            return Ok(Endpoint::Unix(PathBuf::from(path)));
        }
        let host_and_port = |a: &str| {
            a.rsplit_once(':')
                .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok())
        };
        if let Some(rest) = s.strip_prefix("ws://") {
            let authority = rest.split_once('/').map_or(rest, |(a, _)| a);
            if !host_and_port(authority) {
                return Err(format!(
                    "ws:// needs HOST:PORT with a port from 0 to 65535, e.g. ws://127.0.0.1:7879/ \
                     (got {s:?})"
                ));
            }
            return Ok(Endpoint::WebSocket(s.to_owned()));
        }
        if s.starts_with("wss://") {
            return Err(
                "wss:// is not supported; envlight serves plain ws:// (put a TLS proxy in front)"
                    .into(),
            );
        }
        if let Some((scheme, _)) = s.split_once("://") {
            return Err(format!(
                "{scheme}:// is not an envlight endpoint: use unix:PATH, tcp:HOST:PORT, HOST:PORT \
                 or ws://HOST:PORT/"
            ));
        }
        if let Some(addr) = s.strip_prefix("tcp:") {
            if !host_and_port(addr) {
                return Err(format!(
                    "tcp: needs HOST:PORT with a port from 0 to 65535, e.g. tcp:127.0.0.1:7878 (got {s:?})"
                ));
            }
            return Ok(Endpoint::Tcp(addr.to_owned()));
        }
        if s.contains('/') {
            return Ok(Endpoint::Unix(PathBuf::from(s)));
        }
        if host_and_port(s) {
            return Ok(Endpoint::Tcp(s.to_owned()));
        }
        // A bare name in the current folder (`envlight.sock`) is a path if something is there.
        if std::fs::symlink_metadata(s).is_ok() {
            return Ok(Endpoint::Unix(PathBuf::from(s)));
        }
        Err(format!(
            "cannot tell what {s:?} is (no file of that name here): use unix:PATH, \
             tcp:HOST:PORT, HOST:PORT or ws://HOST:PORT/"
        ))
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Endpoint::Unix(path) => write!(f, "unix:{}", path.display()),
            Endpoint::Tcp(addr) => write!(f, "tcp:{addr}"),
            Endpoint::WebSocket(url) => f.write_str(url),
        }
    }
}

/// Errors of the client.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("{endpoint}: {source}")]
    Io {
        endpoint: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{endpoint}: websocket: {message}")]
    WebSocket { endpoint: String, message: String },
    #[error("{endpoint}: {source}")]
    Protocol {
        endpoint: String,
        #[source]
        source: ProtocolError,
    },
}

impl ClientError {
    /// Whether a read timed out (the `read_timeout` of [`Client::connect`] passed without a
    /// message).
    pub fn is_timeout(&self) -> bool {
        matches!(self, ClientError::Io { source, .. }
            if matches!(source.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut))
    }
}

trait ReadWrite: Read + Write + Send {}
impl<T: Read + Write + Send> ReadWrite for T {}

enum Transport {
    Binary {
        stream: Box<dyn ReadWrite>,
        decoder: Decoder,
        /// The bytes of `Client::buf` read and not yet decoded.
        unread: std::ops::Range<usize>,
    },
    JsonLines {
        reader: BufReader<Box<dyn ReadWrite>>,
        /// The line read so far: kept when a read times out in its middle, so that the next
        /// call goes on with it.
        pending: Vec<u8>,
        /// No message has been read yet: the first reply may be binary ([`binary_reply`]).
        first: bool,
    },
    WebSocket(Box<tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>>),
}

/// A subscribed connection.
pub struct Client {
    endpoint: String,
    transport: Transport,
    buf: Vec<u8>,
}

impl Client {
    /// Connects to `endpoint` and subscribes with `request`. `read_timeout` bounds every later
    /// read (`None` = wait forever).
    pub fn connect(
        endpoint: &Endpoint,
        request: &Request,
        read_timeout: Option<Duration>,
    ) -> Result<Client, ClientError> {
        let name = endpoint.to_string();
        let io = |source| ClientError::Io {
            endpoint: name.clone(),
            source,
        };
        let mut subscribe = Vec::new();
        protocol::encode_request(request, &mut subscribe);
        let stream: Box<dyn ReadWrite> = match endpoint {
            Endpoint::Unix(path) => {
                let s = UnixStream::connect(path).map_err(|e| {
                    // A path that exists but is no socket (a frame file, a folder) refuses the
                    // connection; say what it is instead.
                    let what = std::fs::metadata(path).ok().and_then(|m| {
                        use std::os::unix::fs::FileTypeExt;
                        if m.file_type().is_socket() {
                            None
                        } else if m.is_dir() {
                            Some("a directory")
                        } else {
                            Some("a file")
                        }
                    });
                    match what {
                        Some(what) => io(std::io::Error::new(
                            e.kind(),
                            format!(
                                "{what}, not a socket; give the daemon's socket \
                                 (stream.unix_socket), HOST:PORT or ws://HOST:PORT/"
                            ),
                        )),
                        None => io(e),
                    }
                })?;
                s.set_read_timeout(read_timeout).map_err(io)?;
                Box::new(s)
            }
            Endpoint::Tcp(addr) => {
                let s = TcpStream::connect(addr.as_str()).map_err(io)?;
                s.set_read_timeout(read_timeout).map_err(io)?;
                let _ = s.set_nodelay(true);
                Box::new(s)
            }
            Endpoint::WebSocket(url) => {
                let ws_error = |e: tungstenite::Error| ClientError::WebSocket {
                    endpoint: name.clone(),
                    message: e.to_string(),
                };
                // The TCP connection is made here so that `read_timeout` bounds the HTTP
                // upgrade too (a server that accepts and never answers hung the client).
                let authority = url
                    .strip_prefix("ws://")
                    .and_then(|rest| rest.split('/').next())
                    .unwrap_or_default();
                let tcp = TcpStream::connect(authority).map_err(io)?;
                tcp.set_read_timeout(read_timeout).map_err(io)?;
                let _ = tcp.set_nodelay(true);
                let plain = tungstenite::stream::MaybeTlsStream::Plain(tcp);
                let (mut ws, _) =
                    tungstenite::client::client(url.as_str(), plain).map_err(|e| match e {
                        tungstenite::HandshakeError::Interrupted(_) => io(std::io::Error::new(
                            std::io::ErrorKind::TimedOut,
                            "no answer to the WebSocket upgrade",
                        )),
                        tungstenite::HandshakeError::Failure(e) => ws_error(e),
                    })?;
                let message = match request.format {
                    Format::Json => tungstenite::Message::text(protocol::request_to_json(request)),
                    Format::Binary => tungstenite::Message::binary(subscribe),
                };
                ws.send(message).map_err(ws_error)?;
                return Ok(Client {
                    endpoint: name,
                    transport: Transport::WebSocket(Box::new(ws)),
                    buf: Vec::new(),
                });
            }
        };
        let mut stream = stream;
        stream.write_all(&subscribe).map_err(io)?;
        let transport = match request.format {
            Format::Binary => Transport::Binary {
                stream,
                decoder: Decoder::new(),
                unread: 0..0,
            },
            Format::Json => Transport::JsonLines {
                reader: BufReader::new(stream),
                pending: Vec::new(),
                first: true,
            },
        };
        Ok(Client {
            endpoint: name,
            transport,
            buf: vec![0; 64 * 1024],
        })
    }

    /// Hands a decoded light list back (e.g. `FrameMessage::lights` once used): the next
    /// binary light list is decoded into its allocation ([`Decoder::recycle`]). A no-op for
    /// JSON and WebSocket clients.
    pub fn recycle(&mut self, lights: Vec<crate::light::Light>) {
        if let Transport::Binary { decoder, .. } = &mut self.transport {
            decoder.recycle(lights);
        }
    }

    /// The next message; `Ok(None)` when the server closed the connection.
    pub fn next_message(&mut self) -> Result<Option<Message>, ClientError> {
        let endpoint = &self.endpoint;
        let protocol_error = |source| ClientError::Protocol {
            endpoint: endpoint.clone(),
            source,
        };
        let io = |source| ClientError::Io {
            endpoint: endpoint.clone(),
            source,
        };
        match &mut self.transport {
            Transport::Binary {
                stream,
                decoder,
                unread,
            } => loop {
                // Messages are decoded straight from the read buffer (`unread` is the part
                // not yet handed to the decoder); only a message split over reads is copied.
                let mut input = &self.buf[unread.clone()];
                let message = decoder.next_from(&mut input);
                unread.start = unread.end - input.len();
                if let Some(message) = message.map_err(protocol_error)? {
                    return Ok(Some(message));
                }
                let n = stream.read(&mut self.buf).map_err(io)?;
                if n == 0 {
                    decoder.finish().map_err(protocol_error)?;
                    return Ok(None);
                }
                *unread = 0..n;
            },
            Transport::JsonLines {
                reader,
                pending,
                first,
            } => {
                // A line is one message: at most MAX_JSON_MESSAGE_LEN bytes and its newline, so
                // a server that never ends its line cannot grow this buffer without bound.
                let limit = protocol::MAX_JSON_MESSAGE_LEN as u64 + 2;
                let room = limit.saturating_sub(pending.len() as u64);
                // On an error (a timeout) the bytes read stay in `pending` (`read_until`
                // keeps them), and the next call goes on with the line: they were dropped, so
                // a caller that retried after a timeout parsed the rest of a line.
                let read = reader
                    .by_ref()
                    .take(room)
                    .read_until(b'\n', pending)
                    .map_err(io)?;
                if read == 0 && pending.is_empty() {
                    return Ok(None);
                }
                if *first {
                    if let Some(message) = binary_reply(reader, pending).map_err(io)? {
                        pending.clear();
                        return message.map(Some).map_err(protocol_error);
                    }
                    *first = false;
                }
                if pending.len() as u64 >= limit && pending.last() != Some(&b'\n') {
                    pending.clear();
                    return Err(protocol_error(ProtocolError::OversizedJson {
                        len: limit,
                        limit: protocol::MAX_JSON_MESSAGE_LEN,
                    }));
                }
                let line = std::mem::take(pending);
                let text = String::from_utf8(line).map_err(|_| {
                    io(std::io::Error::new(
                        std::io::ErrorKind::InvalidData,
                        "stream did not contain valid UTF-8",
                    ))
                })?;
                protocol::parse_json_message(text.trim_end())
                    .map(Some)
                    .map_err(protocol_error)
            }
            Transport::WebSocket(ws) => loop {
                let message = match ws.read() {
                    Ok(m) => m,
                    Err(
                        tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed,
                    ) => return Ok(None),
                    Err(tungstenite::Error::Io(e)) => return Err(io(e)),
                    Err(e) => {
                        return Err(ClientError::WebSocket {
                            endpoint: endpoint.clone(),
                            message: e.to_string(),
                        })
                    }
                };
                match message {
                    tungstenite::Message::Text(text) => {
                        return protocol::parse_json_message(text.as_str())
                            .map(Some)
                            .map_err(protocol_error)
                    }
                    tungstenite::Message::Binary(bytes) => {
                        return protocol::decode_message(&bytes)
                            .map(Some)
                            .map_err(protocol_error)
                    }
                    tungstenite::Message::Close(_) => return Ok(None),
                    _ => continue,
                }
            },
        }
    }
}

/// The first reply of a JSON Lines subscription when it is a binary message: a daemon at its
/// client limit refuses a connection before it reads the subscribe (error 100,
/// docs/protocol.md), so in binary whatever form was asked. `pending` holds the first "line"
/// read, up to a newline byte, which in a binary message may be one of its bytes; the rest of
/// the message is read here. `None` when `pending` starts no binary message (a JSON line starts
/// with `{`; a binary message has the magic at bytes 4..8). On an error (a timeout) the bytes
/// read so far stay in `pending` for the next call.
fn binary_reply(
    reader: &mut impl BufRead,
    pending: &mut Vec<u8>,
) -> std::io::Result<Option<Result<Message, ProtocolError>>> {
    while pending.len() < 8 && pending.first() != Some(&b'{') {
        let missing = (8 - pending.len()) as u64;
        if reader.by_ref().take(missing).read_to_end(pending)? == 0 {
            break;
        }
    }
    if pending.len() < 8 || pending[4..8] != protocol::MAGIC {
        return Ok(None);
    }
    let len = u32::from_le_bytes([pending[0], pending[1], pending[2], pending[3]]) as usize;
    // An oversized prefix is refused by the decoder from the header alone.
    let total = 4 + len.min(protocol::MAX_MESSAGE_LEN);
    if pending.len() < total {
        let missing = (total - pending.len()) as u64;
        reader.by_ref().take(missing).read_to_end(pending)?;
    }
    let message = &pending[..total.min(pending.len())];
    Ok(Some(protocol::decode_message(message)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_urls_are_refused_when_parsed() {
        for bad in [
            "ws://",
            "ws://127.0.0.1",
            "ws://127.0.0.1:99999/",
            "http://127.0.0.1:7879/",
        ] {
            assert!(bad.parse::<Endpoint>().is_err(), "{bad}");
        }
        assert_eq!(
            "ws://127.0.0.1:7879".parse(),
            Ok(Endpoint::WebSocket("ws://127.0.0.1:7879".into()))
        );
    }

    /// A JSON Lines server whose line never ends: the client stops at one message's size
    /// instead of buffering without bound (it reached 2.2 GB in 4.5 s).
    /// A one-connection TCP server on a thread named `name`: it accepts, reads the client's
    /// (binary) subscribe — closing with it unread would reset the connection, and the reset
    /// could overtake the bytes written — and hands the stream to `serve`. Returns a JSON
    /// client connected to it with `read_timeout`, and the server's thread.
    fn json_client_of(
        name: &str,
        read_timeout: Duration,
        serve: impl FnOnce(TcpStream) + Send + 'static,
    ) -> (Client, std::thread::JoinHandle<()>) {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap().to_string();
        let server = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let (mut stream, _) = listener.accept().unwrap();
                let mut subscribe = [0u8; protocol::HEADER_LEN + protocol::SUBSCRIBE_BODY_LEN];
                stream.read_exact(&mut subscribe).unwrap();
                serve(stream);
            })
            .unwrap();
        let request = Request {
            format: Format::Json,
            ..Request::default()
        };
        let client =
            Client::connect(&Endpoint::Tcp(address), &request, Some(read_timeout)).unwrap();
        (client, server)
    }

    #[test]
    fn an_endless_json_line_is_an_error() {
        let (mut client, server) =
            json_client_of("endless-line", Duration::from_secs(30), |mut stream| {
                let chunk = vec![b'a'; 64 * 1024];
                // Until the client goes away (at most 10 MiB, past the 8 MiB limit).
                for _ in 0..160 {
                    if stream.write_all(&chunk).is_err() {
                        break;
                    }
                }
            });
        let e = client.next_message().unwrap_err().to_string();
        assert!(
            e.contains("JSON message") && e.contains("exceeds the maximum"),
            "{e}"
        );
        drop(client);
        server.join().unwrap();
    }

    /// A JSON line that arrives in two parts with a pause longer than the read timeout between
    /// them: the first call times out, the next one returns the whole message (the part read
    /// before the timeout was dropped, and the next call parsed the rest of the line).
    /// A daemon at its client limit answers before reading the subscribe, so in binary: a JSON
    /// client reads the refusal as the error it is (it reported "invalid JSON message"), also
    /// when a byte of the length prefix is a newline (26 and 252 text bytes: a length of 40,
    /// and of 266 = 0x10A, whose first byte ends a line).
    #[test]
    fn a_json_client_reads_a_binary_refusal() {
        for text_len in [26, 252] {
            let text = "m".repeat(text_len);
            let sent = text.clone();
            let (mut client, server) = json_client_of(
                "binary-refusal",
                Duration::from_secs(30),
                move |mut stream| {
                    let mut refusal = Vec::new();
                    protocol::encode_error(protocol::code::INTERNAL, &sent, &mut refusal);
                    stream.write_all(&refusal).unwrap();
                },
            );
            match client.next_message() {
                Ok(Some(Message::Error { code, message })) => {
                    assert_eq!(code, protocol::code::INTERNAL);
                    assert_eq!(message, text);
                }
                other => panic!("text of {text_len} bytes: {other:?}"),
            }
            server.join().unwrap();
        }
    }

    #[test]
    fn a_json_line_split_by_a_timeout_is_read_whole_on_the_next_call() {
        let line = r#"{"seq":17,"time":0.5,"lights":[{"id":3,"dir":[0.0,1.0,0.0],"rgb":[1.0,0.5,0.25],"solid_angle":0.0625}]}"#;
        let (first, rest) = line.split_at(40);
        let (go_on_tx, go_on_rx) = std::sync::mpsc::sync_channel::<()>(2);
        let (mut client, server) = json_client_of(
            "split-line",
            Duration::from_millis(200),
            move |mut stream| {
                stream.write_all(first.as_bytes()).unwrap();
                // The rest once the client has timed out.
                go_on_rx.recv().unwrap();
                stream.write_all(rest.as_bytes()).unwrap();
                stream.write_all(b"\n").unwrap();
                // Until the client has read it.
                let _ = go_on_rx.recv();
            },
        );
        let e = client.next_message().unwrap_err();
        assert!(e.is_timeout(), "{e}");
        go_on_tx.send(()).unwrap();
        let message = loop {
            match client.next_message() {
                Err(e) if e.is_timeout() => continue,
                other => break other,
            }
        };
        assert_eq!(
            message.unwrap(),
            Some(protocol::parse_json_message(line).unwrap())
        );
        drop(go_on_tx);
        server.join().unwrap();
    }

    #[test]
    fn endpoints_parse_in_every_form() {
        assert_eq!(
            "unix:/run/envlight/envlight.sock".parse(),
            Ok(Endpoint::Unix("/run/envlight/envlight.sock".into()))
        );
        assert_eq!("./x.sock".parse(), Ok(Endpoint::Unix("./x.sock".into())));
        // A bare name is a path when a file of that name is there (tests run in the crate's
        // folder); `localhost` below is not.
        assert_eq!(
            "Cargo.toml".parse(),
            Ok(Endpoint::Unix("Cargo.toml".into()))
        );
        assert_eq!(
            "127.0.0.1:7878".parse(),
            Ok(Endpoint::Tcp("127.0.0.1:7878".into()))
        );
        assert_eq!(
            "tcp:localhost:7878".parse(),
            Ok(Endpoint::Tcp("localhost:7878".into()))
        );
        assert_eq!(
            "ws://127.0.0.1:7879/".parse(),
            Ok(Endpoint::WebSocket("ws://127.0.0.1:7879/".into()))
        );
        for bad in [
            "",
            "unix:",
            "localhost",
            "wss://x:1/",
            "host:port",
            "tcp:",
            "tcp:host",
            "tcp::7878",
            "tcp:h:99999",
        ] {
            assert!(bad.parse::<Endpoint>().is_err(), "{bad:?} parsed");
        }
    }
}
