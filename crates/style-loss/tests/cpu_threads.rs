//! `cpu_threads::candle_ops_on_calling_thread` sets `CANDLE_NUM_THREADS` to 1 once and leaves a
//! value the environment already holds alone (its own test binary: it changes the process's
//! environment).

use style_loss::cpu_threads::{candle_ops_on_calling_thread, CANDLE_THREADS_VARIABLE};

#[test]
fn candle_keeps_its_ops_on_the_calling_thread_unless_told_otherwise() {
    std::env::remove_var(CANDLE_THREADS_VARIABLE);
    assert!(candle_ops_on_calling_thread());
    assert_eq!(std::env::var(CANDLE_THREADS_VARIABLE).as_deref(), Ok("1"));
    std::env::set_var(CANDLE_THREADS_VARIABLE, "3");
    assert!(!candle_ops_on_calling_thread());
    assert_eq!(std::env::var(CANDLE_THREADS_VARIABLE).as_deref(), Ok("3"));
}
