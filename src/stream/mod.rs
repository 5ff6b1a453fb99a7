//! Streaming: how light lists leave the daemon for other processes.
//!
//! For now this is only the wire format ([`protocol`]): the versioned, length-prefixed binary
//! messages and their JSON form that clients on Unix sockets, TCP and WebSocket read and write.
//! The server and per-connection handling (tokio) will live beside it; the format itself has no
//! networking and no async, so it is testable alone. The byte layout is documented in
//! `docs/protocol.md`.

pub mod protocol;

pub use protocol::{
    Decoder, Format, FrameMessage, Message, ProtocolError, Representation, Request,
};
