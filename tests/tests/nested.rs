#[test]
fn nested_cargo_build() {
    let cargo = std::env::var("CARGO").unwrap();
    let status = std::process::Command::new(cargo).args(["build", "-p", "sensors-replay", "--bins"]).status().unwrap();
    assert!(status.success());
}
