//! Sans-IO codecs: bytes in, typed frames out, and the reverse.
