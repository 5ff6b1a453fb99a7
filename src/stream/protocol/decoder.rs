//! [`Decoder`]: messages from a byte stream that arrives in arbitrary pieces, with bounded
//! memory and no panic on any input.

use super::decode::{check_header, decode_body, u16_at};
use super::*;

/// Incremental decoder for a byte stream: [`push`](Decoder::push) bytes as they arrive, in any
/// pieces, and take complete messages with [`next_message`](Decoder::next_message); or, without
/// copying, hand it each read's bytes with [`next_from`](Decoder::next_from) (or the iterator
/// [`feed`](Decoder::feed)), which decodes a message straight from them when they hold all of it
/// and stores only the bytes of a message that is not complete yet.
///
/// Memory stays bounded: the header of the pending message (length prefix, magic, version,
/// type, and whether the length fits the type) is checked as soon as its 12 bytes arrive and
/// before any byte of its body is stored, so the decoder holds at most one message of at most
/// [`MAX_MESSAGE_LEN`] + 4 bytes plus the rest of the latest push. After an error the decoder
/// stays failed: it discards further input and returns the same error again.
///
/// A client that hands each decoded light list back with [`recycle`](Decoder::recycle) has the
/// next one decoded into the same allocation: at a steady light count, no allocation per
/// message.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
    /// Start of the first unconsumed byte in `buf`.
    pos: usize,
    error: Option<ProtocolError>,
    /// A light list handed back, decoded into next.
    spare: Vec<Light>,
}

impl Decoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, mut bytes: &[u8]) {
        if self.error.is_some() {
            return;
        }
        let pending = self.buf.len() - self.pos;
        if pending < HEADER_LEN {
            let take = (HEADER_LEN - pending).min(bytes.len());
            self.buf.extend_from_slice(&bytes[..take]);
            bytes = &bytes[take..];
            if let Err(e) = check_header(&self.buf[self.pos..]) {
                self.fail(e);
                return;
            }
        }
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete message, `Ok(None)` if more bytes are needed, or the error that ends
    /// the stream (returned again on every later call).
    pub fn next_message(&mut self) -> Result<Option<Message>, ProtocolError> {
        if let Some(e) = &self.error {
            return Err(e.clone());
        }
        let pending = &self.buf[self.pos..];
        let len = match check_header(pending) {
            Err(e) => return Err(self.fail(e)),
            Ok(None) => return Ok(None),
            Ok(Some(len)) => len,
        };
        if pending.len() < 4 + len {
            return Ok(None);
        }
        let message_type = u16_at(pending, 10);
        match decode_body(message_type, &pending[HEADER_LEN..4 + len], &mut self.spare) {
            Err(e) => Err(self.fail(e)),
            Ok(message) => {
                self.pos += 4 + len;
                if self.pos == self.buf.len() {
                    self.buf.clear();
                    self.pos = 0;
                } else if self.pos >= self.buf.len() / 2 {
                    self.buf.drain(..self.pos);
                    self.pos = 0;
                }
                Ok(Some(message))
            }
        }
    }

    /// The next message from the bytes stored before and then from `input`, which is advanced
    /// past the bytes taken. Same result as [`push`](Decoder::push)ing `input` and calling
    /// [`next_message`](Decoder::next_message), without the copy: a message that lies whole in
    /// `input` is decoded from there, and only a message that `input` ends inside is stored
    /// (then `input` is left empty and the result is `Ok(None)`). Call it again until it
    /// returns `Ok(None)`: `input` may hold more messages. After an error `input` is left empty
    /// and the decoder is failed, as with `next_message`.
    pub fn next_from(&mut self, input: &mut &[u8]) -> Result<Option<Message>, ProtocolError> {
        if let Some(e) = &self.error {
            *input = &[];
            return Err(e.clone());
        }
        if self.buffered() > 0 {
            // Complete the stored message first: its header, then exactly its remaining bytes.
            let pending = self.buffered();
            if pending < HEADER_LEN {
                let take = (HEADER_LEN - pending).min(input.len());
                self.push(&input[..take]);
                *input = &input[take..];
                if let Some(e) = &self.error {
                    *input = &[];
                    return Err(e.clone());
                }
            }
            let len = match check_header(&self.buf[self.pos..]) {
                Err(e) => {
                    *input = &[];
                    return Err(self.fail(e));
                }
                Ok(None) => return Ok(None), // `input` is used up
                Ok(Some(len)) => len,
            };
            let missing = (4 + len).saturating_sub(self.buffered());
            let take = missing.min(input.len());
            self.push(&input[..take]);
            *input = &input[take..];
            let message = self.next_message();
            if message.is_err() {
                *input = &[];
            }
            return message;
        }
        let bytes = *input;
        let len = match check_header(bytes) {
            Err(e) => {
                *input = &[];
                return Err(self.fail(e));
            }
            Ok(Some(len)) if bytes.len() >= 4 + len => len,
            // Not a whole message: keep what there is (its header checked as it is stored).
            Ok(_) => {
                self.push(bytes);
                *input = &[];
                return match &self.error {
                    Some(e) => Err(e.clone()),
                    None => Ok(None),
                };
            }
        };
        // 4 + len ≥ 12 (check_header): the whole header is there and was checked.
        let message_type = u16_at(bytes, 10);
        match decode_body(message_type, &bytes[HEADER_LEN..4 + len], &mut self.spare) {
            Err(e) => {
                *input = &[];
                Err(self.fail(e))
            }
            Ok(message) => {
                *input = &bytes[4 + len..];
                Ok(Some(message))
            }
        }
    }

    /// The messages in `bytes` (after any stored bytes), decoded as by
    /// [`next_from`](Decoder::next_from): without copying the messages that lie whole in
    /// `bytes`. The iterator ends when `bytes` is used up or after the first error (which
    /// every later call returns again). Bytes left when it is dropped early are stored, as by
    /// [`push`](Decoder::push), so nothing is lost.
    pub fn feed<'b>(&mut self, bytes: &'b [u8]) -> Messages<'_, 'b> {
        Messages {
            decoder: self,
            rest: bytes,
            failed: false,
        }
    }

    /// Hands a decoded light list back: the next light list is decoded into its allocation
    /// (only the largest one handed back is kept).
    pub fn recycle(&mut self, lights: Vec<Light>) {
        if lights.capacity() > self.spare.capacity() {
            self.spare = lights;
        }
    }

    /// Bytes received and not yet returned as messages.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// Call when the stream has ended: an error if it ended inside a message (or the decoder
    /// had failed).
    pub fn finish(&self) -> Result<(), ProtocolError> {
        match &self.error {
            Some(e) => Err(e.clone()),
            None if self.buffered() > 0 => Err(ProtocolError::Truncated {
                buffered: self.buffered(),
            }),
            None => Ok(()),
        }
    }

    fn fail(&mut self, e: ProtocolError) -> ProtocolError {
        self.buf = Vec::new();
        self.pos = 0;
        self.error = Some(e.clone());
        e
    }
}

/// The messages of one read's bytes: [`Decoder::feed`].
#[derive(Debug)]
pub struct Messages<'d, 'b> {
    decoder: &'d mut Decoder,
    rest: &'b [u8],
    failed: bool,
}

impl Iterator for Messages<'_, '_> {
    type Item = Result<Message, ProtocolError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match self.decoder.next_from(&mut self.rest) {
            Ok(message) => message.map(Ok),
            Err(e) => {
                self.failed = true;
                Some(Err(e))
            }
        }
    }
}

impl Drop for Messages<'_, '_> {
    fn drop(&mut self) {
        if !self.rest.is_empty() {
            self.decoder.push(self.rest);
        }
    }
}
