//! lightfold's integration tests: the in-process cluster harness, multi-process and multi-host
//! tests. Every wait has a deadline.
