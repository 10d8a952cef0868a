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

#[test]
fn an_error_raised_on_another_thread_names_that_thread() {
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
