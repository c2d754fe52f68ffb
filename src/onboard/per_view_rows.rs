//! Patch rows per view (`--patch-rows per-view`). A view's in-plane templates are one render
//! turned, so their patches are the same patches seen turned: their rows are kept once, for
//! the view's in-plane-0 template, and the turns point at them. Estimation then turns the
//! query to each short-listed turn instead (`estimate::turned`). Retrieval keeps every
//! template's global descriptor and silhouette, which are small.

use super::model::{ObjectModel, PatchRows};

/// Keeps only each view's in-plane-0 rows and points the view's other templates at them.
/// The model must hold rows per template, in onboarding's order (each view's turns
/// following its in-plane-0 template).
pub fn share_rows_per_view(m: &mut ObjectModel) -> Result<(), String> {
    if m.rows_per_view() {
        return Err(format!("object {:?} already holds its patch rows per view", m.object_id));
    }
    let mut kept = Vec::new();
    let mut next = 0u32;
    let mut owner: Option<(u32, u32, u32)> = None; // (view, start, count) of the rows kept
    for (i, t) in m.templates.iter_mut().enumerate() {
        if t.in_plane == 0 {
            let range = t.patch_start as usize..(t.patch_start + t.patch_count) as usize;
            owner = Some((t.view, next, t.patch_count));
            next += t.patch_count;
            kept.push(range);
        }
        match owner {
            Some((view, start, count)) if view == t.view => (t.patch_start, t.patch_count) = (start, count),
            _ => return Err(format!("object {:?}: template {i} (view {}, turn {}) does not follow its view's in-plane-0 template", m.object_id, t.view, t.in_plane)),
        }
    }
    m.patch_descriptors = m.patch_descriptors.gather(m.local_dim, &kept);
    m.patch_points = m.patch_points.gather(&kept);
    m.patch_cells = m.patch_cells.gather(&kept, 1);
    m.config.patch_rows = PatchRows::PerView;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turns_point_at_their_views_rows_and_the_rest_is_dropped() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let (before, mut m) = (model.clone(), model.clone());
        share_rows_per_view(&mut m).unwrap();
        m.validate().unwrap();
        let kept: u32 = before.templates.iter().filter(|t| t.in_plane == 0).map(|t| t.patch_count).sum();
        assert_eq!(m.patch_count(), kept as usize, "only the in-plane-0 rows are kept");
        assert!(kept > 0 && m.patch_count() < before.patch_count());
        let dim = m.local_dim;
        for (t, (a, b)) in m.templates.iter().zip(&before.templates).enumerate() {
            let owner = &before.templates[t - b.in_plane as usize];
            let (mut got, mut want) = (vec![], vec![]);
            m.patch_descriptors.widen_into(dim, a.patch_start as usize..(a.patch_start + a.patch_count) as usize, &mut got);
            before.patch_descriptors.widen_into(dim, owner.patch_start as usize..(owner.patch_start + owner.patch_count) as usize, &mut want);
            assert_eq!(got, want, "template {t} reads its view's in-plane-0 rows");
        }
        assert!(share_rows_per_view(&mut m).is_err(), "twice");
        // A turn that points elsewhere is refused on load.
        m.templates[1].patch_start += 1;
        assert!(m.validate().unwrap_err().contains("share"));
    }

    /// A shared row's object point, seen by a turned template, lands where
    /// `patch_centre_in_template` says the row's patch sits in that template's crop.
    #[test]
    fn shared_rows_sit_where_their_points_project_in_each_turn() {
        let Some(model) = crate::onboard::test_model::turned_model() else { return };
        let mut m = model.clone();
        share_rows_per_view(&mut m).unwrap();
        let (k, patch) = (m.render_intrinsics, m.grid.patch as f64);
        let mut worst = 0f64;
        for (t, tp) in m.templates.iter().enumerate().filter(|(_, tp)| tp.in_plane != 0) {
            for j in tp.patch_start as usize..(tp.patch_start + tp.patch_count) as usize {
                let p = m.patch_points.point(j).map(|x| x as f64);
                let seen = k.project(&tp.pose.transform_point(&nalgebra::Point3::from(p))).unwrap();
                let (cu, cv) = tp.crop.to_crop(seen.x, seen.y);
                let (eu, ev) = m.patch_centre_in_template(t, m.patch_cells[j]);
                worst = worst.max((cu - eu).hypot(cv - ev));
            }
        }
        // A point is the depth under its patch's centre or a neighbour's (onboarding's
        // search): within a patch. Turned the wrong way, rows land half a crop away.
        assert!(worst < patch, "worst {worst:.1} crop px, patch {patch}");
    }

    #[test]
    fn templates_out_of_order_are_refused() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let mut m = model.clone();
        m.templates.swap(0, 1);
        assert!(share_rows_per_view(&mut m).unwrap_err().contains("does not follow"));
    }
}
