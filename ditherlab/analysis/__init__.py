"""What ditherlab computes from recordings and models: identification of the disturbance model
(:mod:`.identification`), the estimator replayed over a recording (:mod:`.estimation`), the
detection statistics of the paper's §VI-C (:mod:`.detection`, :mod:`.curves`, :mod:`.steady`),
diagnosis and the scoring of candidate effects (:mod:`.diagnosis`, :mod:`.diagnosis_sums`,
:mod:`.scoring`), pose sensitivity (:mod:`.sensitivity`, :mod:`.sensitivity_map`,
:mod:`.sensitivity_plant`), lead-through quality (:mod:`.lead_metrics`), a recording's overview
(:mod:`.overview`) and the per-recording job and summary of a fleet (:mod:`.fleet_job`,
:mod:`.fleet_summary`, :mod:`.sweep_pose`).
"""
