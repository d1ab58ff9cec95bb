//! crokf model file.
