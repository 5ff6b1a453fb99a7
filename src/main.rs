//! envlight command line. (Being written.)
fn main() {}
