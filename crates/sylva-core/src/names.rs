//! Names of models and scenes turned into file names.

/// `name` with everything but ASCII letters, digits, '-' and '_' replaced by '_', at most 64
/// characters, and `fallback` if nothing is left.
pub fn file_stem(name: &str, fallback: &str) -> String {
    let s: String = name
        .chars()
        .take(64)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        fallback.into()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::file_stem;

    #[test]
    fn stems_are_safe_and_bounded() {
        assert_eq!(file_stem("red maple/2", "m"), "red_maple_2");
        assert_eq!(file_stem("", "model"), "model");
        assert_eq!(file_stem(&"é".repeat(100), "m").len(), 64);
    }
}
