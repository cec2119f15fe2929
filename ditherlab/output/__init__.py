"""Outputs for people: the report's pages (:mod:`.report_page`) and figures (:mod:`.figures`),
the diagnosis report (:mod:`.diagnosis_report`), the lead-through and sweep figures
(:mod:`.lead_figures`, :mod:`.sweep_figures`) and the Rerun view (:mod:`.rerun`).

Outputs read what the analyses computed; they never recompute it.
"""
