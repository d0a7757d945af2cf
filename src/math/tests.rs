use super::*;
use std::path::Path;

#[test]
fn functions_agree_with_the_standard_ones_to_a_few_ulps() {
    let close = |a: f64, b: f64| (a - b).abs() <= 4.0 * f64::EPSILON * a.abs().max(b.abs()).max(1e-300);
    for i in 1..200 {
        let x = i as f64 * 0.0731 - 7.0;
        assert!(close(sin(x), x.sin()) && close(cos(x), x.cos()), "{x}");
        assert!(close(atan2(x, 0.7), x.atan2(0.7)), "{x}");
        assert!(close(exp(x), x.exp()), "{x}");
        assert!(close(hypot(x, 3.0), x.hypot(3.0)), "{x}");
        let (s, c) = sin_cos(x);
        assert_eq!((s, c), (sin(x), cos(x)));
        let y = x.abs() + 0.01;
        assert!(close(ln(y), y.ln()) && close(powf(y, 1.7), y.powf(1.7)), "{y}");
        let f = x as f32;
        assert!((sin(f) - f.sin()).abs() <= 4.0 * f32::EPSILON, "{f}");
    }
}

/// The standard library's elementary functions, called as methods.
const STANDARD: &[&str] = &[
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "exp2", "exp_m1",
    "ln", "log", "log2", "log10", "ln_1p", "powf", "cbrt", "hypot", "sin_cos",
];

#[test]
fn no_source_file_calls_the_system_library_for_an_elementary_function() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut found = Vec::new();
    let mut stack = vec![root.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if path.is_dir() {
                // test code builds inputs; it does not write artifacts
                if name != "tests" {
                    stack.push(path);
                }
                continue;
            }
            if !name.ends_with(".rs") || name == "tests.rs" || path == root.join("math.rs") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            // inline test modules close a file
            let code_lines = text.lines().take_while(|l| l.trim() != "#[cfg(test)]");
            for (n, line) in code_lines.enumerate() {
                let code = line.split("//").next().unwrap_or("");
                for f in STANDARD {
                    if code.contains(&format!(".{f}(")) {
                        found.push(format!("{}:{}: .{f}(", path.display(), n + 1));
                    }
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "call crate::math instead:\n{}",
        found.join("\n")
    );
}
