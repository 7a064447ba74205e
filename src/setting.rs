//! A setting a parameter or config file gives that the program cannot run with.

/// The setting's key and what it must be, in one sentence (`standstill.window_s must be finite
/// and > 0, not NaN`); a section that holds the setting adds its name in front ([`Self::within`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidSetting(String);

impl InvalidSetting {
    /// The setting as seen from the section that holds it: `section.` before its key.
    pub fn within(self, section: &str) -> Self {
        InvalidSetting(format!("{section}.{}", self.0))
    }
}

impl From<String> for InvalidSetting {
    fn from(message: String) -> Self {
        InvalidSetting(message)
    }
}

impl From<&str> for InvalidSetting {
    fn from(message: &str) -> Self {
        InvalidSetting(message.into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_section_names_itself_before_the_key() {
        let e = InvalidSetting::from("window_s must be finite and > 0, not NaN").within("standstill").within("pipeline");
        assert_eq!(e.to_string(), "pipeline.standstill.window_s must be finite and > 0, not NaN");
    }
}
