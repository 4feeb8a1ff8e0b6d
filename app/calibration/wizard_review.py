"""What the calibration wizard's flatfield, distortion and calibration-object pages show once
their step's result is in, and the edits made there: another distortion model, a frame left out
of the solve, a bead's label corrected by hand (a mixin of
:class:`~app.calibration.wizard.CalibrationWizard`; the computing is :mod:`app.calibration.jobs`).

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import numpy as np

from .jobs import flatfield_for, job_beads, job_distortion, job_frame, job_refit
from .wizard_pages import _fill, _fmt


class StepReview:
    """The flatfield, distortion and object-frames pages of the wizard, after their step."""

    # ------------------------------------------------------------------ flatfield
    def _enter_flatfield(self) -> None:
        folder = self.session_edit.text().strip()
        r = self.results.get("flatfield")
        if r is not None and r.get("folder") != folder:
            self._invalidate("flatfield", "distortion", "beads", "solve")
            r = None
        if r is None:
            if self._running is None:
                self._submit("flatfield", flatfield_for, folder)
            return
        setup = r["setup"]
        for view, cam, img, (ff, kv) in zip(self.ff_views, setup.cameras, r["corrected"], r["flatfields"],
                                            strict=True):
            view.set_image(img, levels=(0.0, 1.25))
            from .figures import field_fraction

            view.caption = (f"{cam}: a corrected empty-field frame" + (f" ({kv:g} kV)" if kv else "")
                            + f"; {100 * field_fraction(ff):.0f} % of the image inside the field")
            view.set_points(np.zeros((0, 2)))
        self.rolloff_view.set_figure(r["rolloff"])

    # ------------------------------------------------------------------ distortion
    def _enter_distortion(self) -> None:
        r = self.results.get("distortion")
        if r is None:
            ff = self.results.get("flatfield")
            if ff is not None and self._running is None:
                self._submit("distortion", job_distortion, ff["setup"], ff["flatfields"])
            return
        if self.dist_camera.count() != len(r["dist"].cameras):
            self.dist_camera.blockSignals(True)
            self.dist_camera.clear()
            self.dist_camera.addItems([c.name for c in r["dist"].cameras])
            self.dist_camera.blockSignals(False)
        self._draw_distortion()

    def _draw_distortion(self) -> None:
        r = self.results.get("distortion")
        if r is None:
            return
        k = max(self.dist_camera.currentIndex(), 0)
        c, view = r["dist"].cameras[k], r["views"][k]
        g = c.grid
        n = np.linalg.norm(view["resid"], axis=1)
        scale = 10.0 / max(float(np.percentile(n, 99)) if n.size else 1.0, 1e-6)
        self.grid_view.set_image(view["image"])
        self.grid_view.set_points(view["uv"], vectors=view["resid"], vector_scale=scale)
        st = g.residuals.to_dict()["mm"]
        self.grid_view.caption = (f"{c.name}: {len(view['uv'])} grid points of {view['ref']}; residual "
                                  f"vectors × {scale:.0f}")
        rows = []
        for t in g.table:
            rows.append([t["model"], _fmt(t.get("rms_px")), _fmt(t.get("rms_mm"), 4),
                         "chosen" if t["model"] == g.spec.label else ""])
        if not any(row[3] for row in rows):
            rows.append([g.spec.label, "(given)", "", "chosen"])
        _fill(self.model_table, rows)
        gl = c.glare
        glare = (f"\nVeiling glare (lead-disc frames): {100 * gl.fraction:.2f} ± {100 * gl.fraction_sd:.2f} "
                 f"% over σ {gl.sigma_px * g.mm_per_px:.1f} mm, undone after the flatfield." if gl is not None
                 else "\nNo lead-disc frames: veiling glare not measured.")
        self.dist_info.setText(f"{c.name}: {g.spec.label}; grid residual RMS {st['rms']:.4f} mm (max "
                               f"{st['max']:.4f} mm) over {len(g.ideal_uv)} points of {g.n_placements} "
                               f"placement(s)." + "".join(f"\n{n}" for n in g.notes) + glare)

    def refit(self) -> None:
        """Fit the chosen model to the current camera's grid points (later steps are redone)."""
        r, ff = self.results.get("distortion"), self.results.get("flatfield")
        if r is None or self._running is not None:
            return
        self._submit("refit", job_refit, ff["setup"], r["dist"], max(self.dist_camera.currentIndex(), 0),
                     self.model_combo.currentText().strip())

    # ------------------------------------------------------------------ object frames
    def _enter_object(self) -> None:
        b = self.results.get("beads")
        if b is None:
            ff, d = self.results.get("flatfield"), self.results.get("distortion")
            if d is not None and self._running is None:
                self._submit("beads", job_beads, ff["setup"], d["dist"])
            return
        setup = self.results["flatfield"]["setup"]
        if self.bead_combo.count() != len(setup.target):
            self.bead_combo.clear()
            self.bead_combo.addItems([str(i) for i in setup.target.bead_ids])
        row = max(self.frame_list.currentRow(), 0)
        self._fill_frames()
        self.frame_list.setCurrentRow(row)
        self._select_frame(row)

    def _fill_frames(self) -> None:
        b = self.results["beads"]
        self.frame_list.blockSignals(True)
        row = self.frame_list.currentRow()
        self.frame_list.clear()
        for k, fr in enumerate(b.frames):
            labs = "/".join(str(lab.n_labelled) for lab in fr.labellings)
            state = "excluded" if k in b.excluded else ("ok" if fr.ok else f"not used: {fr.reason}")
            manual = " (edited)" if any(lab.manual for lab in fr.labellings) else ""
            self.frame_list.addItem(f"frame {k}: {labs} labelled, {state}{manual}")
        self.frame_list.setCurrentRow(row)
        self.frame_list.blockSignals(False)
        n = sum(1 for k, fr in enumerate(b.frames) if fr.ok and k not in b.excluded)
        setup = self.results["flatfield"]["setup"]
        static = getattr(setup.static, "name", "static object")
        bad = [f for f in b.static_frames if not f.ok]
        if not b.static_frames:
            cube = (f"no static {static} frame: the lab frame will be the {setup.target.name}'s first "
                    "labelled frame (with a warning)")
        elif bad:
            cube = (f"the static {static} frame could not be labelled ({bad[0].reason}): the solve needs "
                    f"it for the lab frame, unless the {setup.target.name}'s first labelled frame is "
                    "chosen on the Solve page")
        else:
            cube = f"the static {static} frame is labelled (it defines the lab frame)"
        self.object_info.setText(f"{n} of {len(b.frames)} frames go to the solve; {cube}.")

    def _select_frame(self, k: int) -> None:
        b = self.results.get("beads")
        if b is None or k < 0:
            return
        self._picked = None
        self.assign_button.setEnabled(False)
        self.exclude_box.setChecked(k in b.excluded)
        if k in self._frames:
            self._draw_frame()
        else:
            ff, d = self.results["flatfield"], self.results["distortion"]
            for v in self.object_views:
                v.caption = f"frame {k}: correcting…"
                v.update()
            self.pool.submit("frame", lambda: (k, job_frame(ff["setup"], d["dist"], b, k)))

    def _draw_frame(self) -> None:
        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k not in self._frames:
            return
        setup = self.results["flatfield"]["setup"]
        fr = b.frames[k]
        for v, (view, img) in enumerate(zip(self.object_views, self._frames[k], strict=True)):
            lab = fr.labellings[v]
            ids = [str(setup.target.bead_ids[i]) if i >= 0 else "" for i in lab.labels]
            cols = ["#40ff40" if i >= 0 else "#ff4040" for i in lab.labels]
            view.set_image(img)
            view.set_points(lab.uv, colors=cols, labels=ids)
            if self._picked is not None and self._picked[0] == v:
                view.selected = self._picked[1]
            view.caption = (f"{setup.cameras[v]}, frame {k}: {lab.n_labelled} of {len(lab.uv)} detections "
                            f"labelled" + (" (edited)" if lab.manual else ""))

    def _click_bead(self, v: int, u: float, y: float) -> None:
        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k < 0:
            return
        i = self.object_views[v].nearest(u, y)
        self._picked = None if i is None else (v, i)
        self.assign_button.setEnabled(i is not None)
        for w, view in enumerate(self.object_views):
            view.selected = i if w == v else None
            view.update()
        if i is not None:
            lab = b.frames[k].labellings[v]
            cur = int(lab.labels[i])
            if cur >= 0:
                self.bead_combo.setCurrentIndex(cur)
            ids = self.results["flatfield"]["setup"].target.bead_ids
            now = f"bead {ids[cur]}" if cur >= 0 else "unlabelled"
            self.status.setText(f"detection {i} of view {v + 1} selected (now {now}); choose its id and "
                                "Assign")

    def assign_label(self) -> None:
        """The picked detection becomes the bead chosen in the list (the solve is redone)."""
        from core.calibration.session import relabel

        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or self._picked is None:
            return
        v, i = self._picked
        bead = self.bead_combo.currentIndex()
        self.results["beads"] = relabel(b, k, v, i, bead)
        self._invalidate("solve")
        self.status.setText(f"frame {k}, view {v + 1}: detection {i} is now bead "
                            f"{self.bead_combo.currentText()}")
        self._fill_frames()
        self._draw_frame()

    def _toggle_exclude(self, checked: bool) -> None:
        from core.calibration.session import exclude_frames

        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k < 0:
            return
        ex = set(b.excluded) | {k} if checked else set(b.excluded) - {k}
        self.results["beads"] = exclude_frames(b, ex)
        self._invalidate("solve")
        self._fill_frames()

