//! The wire protocol's decoders on arbitrary bytes: one message at a time, a stream fed in
//! chunks (the first byte sets the chunk length), and the JSON forms of frames and requests.
#![no_main]

use envlight::stream::protocol::{decode_message, parse_json_message, parse_json_request, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = decode_message(data);

    if let Some((&chunk, stream)) = data.split_first() {
        let mut decoder = Decoder::new();
        for piece in stream.chunks(usize::from(chunk).max(1)) {
            decoder.push(piece);
            while let Ok(Some(_)) = decoder.next_message() {}
        }
        let _ = decoder.finish();
    }

    let text = String::from_utf8_lossy(data);
    let _ = parse_json_message(&text);
    let _ = parse_json_request(&text);
});
