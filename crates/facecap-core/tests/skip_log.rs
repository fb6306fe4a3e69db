#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Skips are visible and counted: `paths::skip` appends to `$FACECAP_SKIP_LOG` (what
//! `scripts/test.sh` counts), and `paths::skip_missing_data` fails the test under
//! `CI=true` when the shared data is present. One test in its own binary, because it
//! sets environment variables.

use facecap_core::paths::{shared_data_dir, skip, skip_missing_data, SKIP_LOG_ENV};

#[test]
fn skips_reach_the_log_and_fail_under_ci_with_data() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("skips.txt");
    std::env::set_var(SKIP_LOG_ENV, &log);
    std::env::remove_var("CI");
    skip("skip_log: optional tool absent");
    skip_missing_data("skip_log: data absent");
    let text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(
        text.lines().collect::<Vec<_>>(),
        ["SKIP: skip_log: optional tool absent", "SKIP: skip_log: data absent"]
    );
    // Under CI=true with the shared data present a missing-data skip is a failure;
    // without the data it stays a skip.
    std::env::set_var("CI", "true");
    let r = std::panic::catch_unwind(|| skip_missing_data("skip_log: data absent under CI"));
    assert_eq!(r.is_err(), shared_data_dir().is_some());
    // An optional tool's skip never fails.
    assert!(std::panic::catch_unwind(|| skip("skip_log: optional under CI")).is_ok());
    std::env::remove_var("CI");
    std::env::remove_var(SKIP_LOG_ENV);
    assert_eq!(std::fs::read_to_string(&log).unwrap().lines().count(), 4);
}
