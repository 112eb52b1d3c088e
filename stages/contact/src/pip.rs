//! PIP's contact rule (work in progress).
