//! crokf runtime.
