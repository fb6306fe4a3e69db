//! Video landmark tracker (work in progress).
