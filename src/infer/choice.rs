//! Which correction runs on this IMU, and why: the guard that keeps the pipeline no worse than
//! the rest calibration a user does at power-on.
//!
//! A learned correction is for the IMU it learned. On an IMU the model was neither trained nor
//! adapted on, the bundled model was measured worse than the raw gyro and far worse than the
//! bias measured at rest (docs/poweron.md); there the model is not applied and the power-on
//! bias from the standstills is. A model adapted after its support's power-on bias was
//! removed gets the same removal before it, so what it learned (the lasting errors) carries to
//! the next power-on and the constant it did not learn is measured afresh.

/// What the corrector is for the IMU it runs on, as established when it was loaded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelDomain {
    /// No model: the gyro as measured.
    NoModel,
    /// The model was trained on this IMU (named by `imu_calibration`), on its raw stream: its
    /// correction covers this IMU's bias as in training, so a rest is not subtracted before it.
    Trained,
    /// Trained on this IMU with each training recording's power-on bias removed
    /// (`dataset.power_on_bias: remove`): this power-on's is removed before it.
    TrainedAfterPowerOnBias,
    /// Adapted on this IMU after the support's power-on bias was removed.
    AdaptedAfterPowerOnBias,
    /// The same, with the gyro calibration alone kept (Ĉ_ω, the networks' correction off).
    CalibratedAfterPowerOnBias,
    /// The same with a constant bias offset in motion (the networks' correction a constant):
    /// kept only where other power-ons of the IMU showed it lasts.
    CalibratedWithOffsetAfterPowerOnBias,
    /// Adapted on this IMU with the support's power-on constant inside (an adaptation made
    /// before the power-on rule): run as it was made.
    AdaptedWithBias,
    /// Neither trained nor adapted on this IMU.
    NewImu,
}

impl ModelDomain {
    /// A loaded model's domain from its metadata and the IMU it is run as (`imu_calibration`).
    pub fn of(meta: &crate::model::ModelMetadata, imu: Option<&str>) -> Self {
        match (&meta.adapted_from, imu) {
            (Some(_), _) if meta.power_on_bias_removed && meta.correction_networks_off => ModelDomain::CalibratedAfterPowerOnBias,
            (Some(_), _) if meta.power_on_bias_removed && meta.correction_constant_rad_s.is_some() => {
                ModelDomain::CalibratedWithOffsetAfterPowerOnBias
            }
            (Some(_), _) if meta.power_on_bias_removed => ModelDomain::AdaptedAfterPowerOnBias,
            (Some(_), _) => ModelDomain::AdaptedWithBias,
            (None, Some(name)) if meta.knows_imu(name) && meta.power_on_bias_removed => ModelDomain::TrainedAfterPowerOnBias,
            (None, Some(name)) if meta.knows_imu(name) => ModelDomain::Trained,
            _ => ModelDomain::NewImu,
        }
    }
}

/// The training recordings' power-on biases of IMU `imu`, where the model was trained on it
/// with them removed (empty otherwise: a model trained on the raw stream has them inside).
pub fn trained_power_ons<'m>(meta: &'m crate::model::ModelMetadata, imu: Option<&str>) -> &'m [crate::model::export::TrainedPowerOn] {
    match imu {
        Some(name) if ModelDomain::of(meta, imu) == ModelDomain::TrainedAfterPowerOnBias => {
            meta.trained_power_on_biases.get(name).map_or(&[], Vec::as_slice)
        }
        _ => &[],
    }
}

/// What those power-ons predict for this one, as a bias memory file's would
/// ([`crate::bias_memory::BiasMemory::predict`]: two at least, per axis where the 95 %
/// prediction interval excludes zero).
pub fn predict_from(power_ons: &[crate::model::export::TrainedPowerOn], floor_stddev: f64) -> Option<crate::standstill::BiasPrediction> {
    let memory = crate::bias_memory::BiasMemory {
        power_ons: power_ons
            .iter()
            .map(|p| crate::bias_memory::RememberedBias {
                bias_rad_s: p.bias_rad_s,
                stddev_rad_s: p.stddev_rad_s,
                still_s: p.still_s,
                power_on: p.recording.clone(),
            })
            .collect(),
    };
    memory.predict(None, floor_stddev)
}

/// The correction the pipeline applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Correction {
    /// The gyro as measured.
    Raw,
    /// The gyro minus the power-on bias measured at standstills.
    PowerOnBias,
    /// The power-on bias removed, then the model.
    PowerOnBiasThenModel,
    /// The model on the gyro as measured.
    Model,
}

impl Correction {
    pub fn name(self) -> &'static str {
        match self {
            Correction::Raw => "raw",
            Correction::PowerOnBias => "power-on bias",
            Correction::PowerOnBiasThenModel => "power-on bias, then the model",
            Correction::Model => "model",
        }
    }

    /// The standstills' bias is subtracted from the gyro.
    pub fn removes_power_on_bias(self) -> bool {
        matches!(self, Correction::PowerOnBias | Correction::PowerOnBiasThenModel)
    }

    /// The model is stepped.
    pub fn runs_model(self) -> bool {
        matches!(self, Correction::Model | Correction::PowerOnBiasThenModel)
    }
}

/// The rule: which correction for which model, with its reason for /diagnostics and `eval`.
/// `power_on_bias`: the standstill estimate is on; `model_on_new_imu`: the user asked for the
/// model on an IMU it does not know.
pub fn choose(domain: ModelDomain, power_on_bias: bool, model_on_new_imu: bool) -> (Correction, &'static str) {
    match domain {
        ModelDomain::NoModel if power_on_bias => (Correction::PowerOnBias, "no model: the power-on bias measured at standstills"),
        ModelDomain::NoModel => (Correction::Raw, "no model and power_on_bias off: the gyro as measured"),
        ModelDomain::Trained => (Correction::Model, "the model was trained on this IMU (imu_calibration)"),
        ModelDomain::TrainedAfterPowerOnBias if power_on_bias => (
            Correction::PowerOnBiasThenModel,
            "the model was trained on this IMU with each recording's power-on bias removed (imu_calibration): this power-on's is removed before it",
        ),
        ModelDomain::TrainedAfterPowerOnBias => {
            (Correction::Model, "power_on_bias off: the model trained without its recordings' power-on biases runs on the raw gyro")
        }
        ModelDomain::AdaptedWithBias => {
            (Correction::Model, "the model was adapted on this IMU with its support's constant inside (no power-on rule)")
        }
        ModelDomain::AdaptedAfterPowerOnBias if power_on_bias => {
            (Correction::PowerOnBiasThenModel, "the model was adapted on this IMU after its power-on bias was removed")
        }
        ModelDomain::AdaptedAfterPowerOnBias => {
            (Correction::Model, "power_on_bias off: the adapted model runs on the raw gyro (it was adapted without its support's bias)")
        }
        ModelDomain::CalibratedAfterPowerOnBias if power_on_bias => (
            Correction::PowerOnBiasThenModel,
            "the gyro calibration adapted on this IMU (its Ĉ_ω, the networks off) after its power-on bias was removed",
        ),
        ModelDomain::CalibratedAfterPowerOnBias => {
            (Correction::Model, "power_on_bias off: the gyro calibration adapted on this IMU runs on the raw gyro (it was fitted without its support's bias)")
        }
        ModelDomain::CalibratedWithOffsetAfterPowerOnBias if power_on_bias => (
            Correction::PowerOnBiasThenModel,
            "the gyro calibration and bias offset in motion adapted on this IMU (kept where other power-ons showed it lasts) after its power-on bias was removed",
        ),
        ModelDomain::CalibratedWithOffsetAfterPowerOnBias => (
            Correction::Model,
            "power_on_bias off: the gyro calibration and bias offset in motion adapted on this IMU run on the raw gyro (fitted without its support's bias)",
        ),
        ModelDomain::NewImu if model_on_new_imu => (Correction::Model, "model_on_new_imu: the model on an IMU it was neither trained nor adapted on"),
        ModelDomain::NewImu if power_on_bias => (
            Correction::PowerOnBias,
            "model not applied: it was neither trained nor adapted on this IMU (set imu_calibration, or adapt it); the power-on bias instead",
        ),
        ModelDomain::NewImu => (Correction::Raw, "model not applied: a new IMU, and power_on_bias off: the gyro as measured"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_imu_gets_the_rest_calibration_not_the_model() {
        assert_eq!(choose(ModelDomain::NewImu, true, false).0, Correction::PowerOnBias);
        assert_eq!(choose(ModelDomain::NewImu, true, true).0, Correction::Model);
        assert_eq!(choose(ModelDomain::NewImu, false, false).0, Correction::Raw);
        assert_eq!(choose(ModelDomain::Trained, true, false).0, Correction::Model);
        assert_eq!(choose(ModelDomain::TrainedAfterPowerOnBias, true, false).0, Correction::PowerOnBiasThenModel);
        assert_eq!(choose(ModelDomain::TrainedAfterPowerOnBias, false, false).0, Correction::Model);
        assert_eq!(choose(ModelDomain::AdaptedAfterPowerOnBias, true, false).0, Correction::PowerOnBiasThenModel);
        assert_eq!(choose(ModelDomain::CalibratedAfterPowerOnBias, true, false).0, Correction::PowerOnBiasThenModel);
        assert!(choose(ModelDomain::CalibratedAfterPowerOnBias, true, false).1.contains("gyro calibration"));
        assert_eq!(choose(ModelDomain::CalibratedWithOffsetAfterPowerOnBias, true, false).0, Correction::PowerOnBiasThenModel);
        assert!(choose(ModelDomain::CalibratedWithOffsetAfterPowerOnBias, true, false).1.contains("bias offset in motion"));
        assert_eq!(choose(ModelDomain::NoModel, true, false).0, Correction::PowerOnBias);
    }
}
