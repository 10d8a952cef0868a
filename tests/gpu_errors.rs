//! A GPU error is reported with the thread whose call raised it when another thread finds it
//! (the test binaries share one device between their test threads: `common::gpu()`). Its own
//! binary, so that no other test drains the device's errors meanwhile.

mod common;

/// A buffer that asks for MAP_READ with STORAGE (a validation error without
/// MAPPABLE_PRIMARY_BUFFERS), created on the calling thread.
fn raise_a_validation_error(ctx: &palpate::gpu::GpuContext) {
    let _ = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("invalid on purpose"),
        size: 16,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
}

/// The tests of this binary run on threads of their own and share one device: they take its
/// errors one test at a time.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    TURN.lock().unwrap_or_else(|p| p.into_inner())
}

#[test]
fn an_error_raised_on_another_thread_names_that_thread() {
    let _turn = one_at_a_time();
    let ctx = common::gpu();
    ctx.wait().expect("no error before the test");
    // Raised here and found here: the message alone.
    raise_a_validation_error(&ctx);
    let own = ctx.wait().expect_err("the invalid buffer raised no error");
    assert!(!own.to_string().contains("raised on thread"), "{own}");
    // Raised by a thread named like a test and found here: the message names it.
    let raiser = ctx.clone();
    std::thread::Builder::new()
        .name("some_other_test".into())
        .spawn(move || raise_a_validation_error(&raiser))
        .unwrap()
        .join()
        .unwrap();
    let other = ctx.wait().expect_err("the other thread's error was lost");
    assert!(
        other
            .to_string()
            .contains("(raised on thread 'some_other_test')"),
        "{other}"
    );
    ctx.wait().expect("each error is reported once");
}

/// A thread finds its own error first even when another thread's came before it, and the
/// other's stays to be reported once, naming its thread (a check used to drain every error
/// and return the oldest: the checking thread's own failure was lost). Object creation
/// checked through the thread's own error scopes (`GpuContext::scoped`, which kernel and
/// bind-group creation use) neither takes nor is blamed for another thread's error.
#[test]
fn a_thread_finds_its_own_error_before_another_threads() {
    let _turn = one_at_a_time();
    let ctx = common::gpu();
    // Each check takes one error: a bounded drain of what earlier tests left.
    for _ in 0..64 {
        if ctx.check_errors().is_ok() {
            break;
        }
    }
    let other_thread = |ctx: &std::sync::Arc<palpate::gpu::GpuContext>| {
        let raiser = ctx.clone();
        std::thread::Builder::new()
            .name("earlier_test".into())
            .spawn(move || raise_a_validation_error(&raiser))
            .unwrap()
            .join()
            .unwrap();
    };
    other_thread(&ctx);
    raise_a_validation_error(&ctx);
    let own = ctx
        .check_errors()
        .expect_err("this thread's error was lost");
    assert!(!own.to_string().contains("raised on thread"), "{own}");
    let other = ctx
        .check_errors()
        .expect_err("the other thread's error was lost");
    assert!(other.to_string().contains("'earlier_test'"), "{other}");
    ctx.check_errors().expect("each error is reported once");

    // Scoped creation beside another thread's pending error.
    other_thread(&ctx);
    let made = ctx.scoped("a valid buffer", || {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("valid"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        })
    });
    assert!(
        made.is_ok(),
        "blamed for another thread's error: {:?}",
        made.err()
    );
    let failed = ctx
        .scoped("the invalid buffer", || raise_a_validation_error(&ctx))
        .expect_err("the scope missed the invalid buffer");
    assert!(
        failed.to_string().contains("the invalid buffer: ")
            && failed.to_string().contains("invalid on purpose"),
        "{failed}"
    );
    let other = ctx
        .check_errors()
        .expect_err("the scope took the other thread's error");
    assert!(other.to_string().contains("'earlier_test'"), "{other}");
    ctx.check_errors().expect("each error is reported once");
}
