//! Streaming: how light lists (and ASG and wavelet sets) leave the daemon for other processes.
//!
//! - [`protocol`]: the versioned, length-prefixed binary messages and their JSON form
//!   (docs/protocol.md); no networking and no async, so it is testable alone.
//! - [`server`]: the tokio server for Unix sockets, TCP and WebSocket, one task per client
//!   (handshake, input, slow path), newest-frame-wins for slow clients.
//! - `fanout`: the thread that writes each publication to every Unix-socket and TCP client
//!   that keeps up in one pass, with non-blocking writes (no task wake-up per client).
//! - [`client`]: a small blocking client (used by `envlight subscribe`, the examples and the
//!   tests).

pub mod client;
mod fanout;
pub mod protocol;
pub mod server;

pub use fanout::{FANOUT_THREAD_NAME, PASS_THREAD_NAME};
pub use protocol::{
    AsgFrameMessage, Decoder, Format, FrameMessage, Message, Messages, ProtocolError,
    Representation, Request, ShFrame, ShFrameMessage, WaveletFrame, WaveletFrameMessage,
};
pub use server::{
    BoundAddresses, FanoutOn, PublisherPass, ServerConfig, StreamServer, Streamed, Streams,
};
