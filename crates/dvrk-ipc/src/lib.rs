//! dvrk-ipc
