//! How hard the depth detector's candidates are estimated. The detector offers each surface
//! of an object's size to every object of that size, so most of its candidates are not the
//! object they are estimated for, and with several objects searched their estimates are
//! most of a frame's time (docs/detection.md, "Screening"). With depth, refining only the
//! verification hypotheses whose outline agrees best where they start answered as many
//! instances, one more or one fewer, on the real YCB-V frames and on generated scenes over
//! real frames, for a tenth less time on frames with 3–4 objects (none with 8 searched);
//! RRC turned off as well saved a third but lost a tenth of the AR on the generated scenes
//! (docs/detection.md, "Lighter estimates for the detector's candidates"). The depth's own
//! template views (`VerifyConfig::depth_views`) are left out too: they fit a candidate of
//! the wrong object to the surface as well as the right one's, and on the generated scenes
//! over real frames the detector's answers lost 0.03–0.06 AR with them (docs/estimation.md,
//! "Views found in the depth").

use super::EstimateConfig;
use std::borrow::Cow;

/// Hypotheses refined in full for a light estimate (`VerifyConfig::refined`): the
/// pipeline's pose and the 11 others whose outline agrees best where they start.
pub const LIGHT_REFINED: usize = 12;

/// How the depth detector's screened candidates are estimated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum CandidateEffort {
    /// At most [`LIGHT_REFINED`] verification hypotheses refined, no views searched in the
    /// depth.
    #[default]
    Light,
    /// As a caller's mask: the configuration as it is.
    Full,
}

impl CandidateEffort {
    /// The configuration a screened candidate is estimated with under `cfg`.
    pub fn applied(cfg: &EstimateConfig) -> Cow<'_, EstimateConfig> {
        match cfg.candidate_effort {
            CandidateEffort::Full => Cow::Borrowed(cfg),
            CandidateEffort::Light => {
                let mut light = cfg.clone();
                // 0 refines every hypothesis.
                if light.verify.refined == 0 || light.verify.refined > LIGHT_REFINED {
                    light.verify.refined = LIGHT_REFINED;
                }
                light.verify.depth_views = 0;
                Cow::Owned(light)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_caps_the_refined_hypotheses_and_full_keeps_the_caller_s() {
        let cfg = EstimateConfig::default();
        assert!(cfg.verify.refined == 0 && cfg.candidate_effort == CandidateEffort::Light);
        let light = CandidateEffort::applied(&cfg);
        assert_eq!(light.verify.refined, LIGHT_REFINED);
        // Everything else as the caller's.
        assert_eq!(light.verify.depth_views, 0);
        let mut back = light.clone().into_owned();
        (back.verify.refined, back.verify.depth_views) = (0, cfg.verify.depth_views);
        assert_eq!(back, cfg);
        // A caller's smaller number stays.
        let mut fewer = cfg.clone();
        fewer.verify.refined = 6;
        assert_eq!(CandidateEffort::applied(&fewer).verify.refined, 6);
        let full = EstimateConfig { candidate_effort: CandidateEffort::Full, ..cfg.clone() };
        assert!(matches!(CandidateEffort::applied(&full), Cow::Borrowed(c) if *c == full));
    }

    #[test]
    fn the_effort_reads_and_writes_in_lower_case_and_configs_without_it_are_light() {
        assert_eq!(serde_json::to_string(&CandidateEffort::Full).unwrap(), "\"full\"");
        assert_eq!(serde_json::from_str::<CandidateEffort>("\"light\"").unwrap(), CandidateEffort::Light);
        let mut v = serde_json::to_value(EstimateConfig::default()).unwrap();
        v.as_object_mut().unwrap().remove("candidate_effort");
        assert_eq!(serde_json::from_value::<EstimateConfig>(v).unwrap().candidate_effort, CandidateEffort::Light);
    }
}
