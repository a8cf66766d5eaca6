//! The class of any cause in an error chain (`anyhow` at the binary edge, a
//! daemon's log): a pipeline [`Error`], or one of the typed errors it wraps
//! met on its own (an io error of `inspect` or `convert`, a stage error
//! inside another library error). This is the one place that names every
//! stage's error type; the stages themselves name only [`Error`].

use super::asset::StageError;
use super::error::{Error, ErrorClass, StageFailure};
use super::fabric_test::FabricTestError;
use super::pattern::PatternStageError;
use super::simulate::SimulateError;
use super::submit::SubmitError;
use super::yls::YlsError;
use crate::io::IoError;

/// The class of one cause in an error chain, `None` for anything knitvox
/// does not classify. Callers take the first cause that has a class.
pub fn class_of(cause: &(dyn std::error::Error + 'static)) -> Option<ErrorClass> {
    if let Some(e) = cause.downcast_ref::<Error>() {
        Some(e.class())
    } else if let Some(e) = cause.downcast_ref::<IoError>() {
        Some(e.class().into())
    } else if let Some(e) = cause.downcast_ref::<StageError>() {
        Some(StageFailure::class(e))
    } else if let Some(e) = cause.downcast_ref::<SimulateError>() {
        Some(StageFailure::class(e))
    } else if let Some(e) = cause.downcast_ref::<PatternStageError>() {
        Some(StageFailure::class(e))
    } else if let Some(e) = cause.downcast_ref::<YlsError>() {
        Some(StageFailure::class(e))
    } else if let Some(e) = cause.downcast_ref::<FabricTestError>() {
        Some(StageFailure::class(e))
    } else if let Some(e) = cause.downcast_ref::<SubmitError>() {
        Some(StageFailure::class(e))
    } else if cause.is::<crate::embed::EmbedError>()
        || cause.is::<crate::fit::FitError>()
        || cause.is::<crate::geom::GeomError>()
    {
        Some(ErrorClass::BadInput)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_of_finds_a_stage_error_inside_a_chain() {
        let e = anyhow::Error::new(Error::from(
            crate::pipeline::simulate::SimulateError::Unavailable("no GPU".into()),
        ))
        .context("simulating");
        let class = e.chain().find_map(class_of);
        assert_eq!(class, Some(ErrorClass::Unavailable));
        let e = anyhow::anyhow!("something else");
        assert_eq!(e.chain().find_map(class_of), None);
        // A stage error met on its own has the class it has inside Error.
        let bare = crate::pipeline::pattern::PatternStageError::Pattern(
            crate::yarn::pattern::PatternError::BadParameter {
                name: "courses",
                value: 0.0,
                message: "must be positive".into(),
            },
        );
        let class = bare.class();
        assert_eq!(class, ErrorClass::Usage);
        assert_eq!(class_of(&bare), Some(class));
        assert_eq!(class_of(&Error::from(bare)), Some(class));
    }
}
