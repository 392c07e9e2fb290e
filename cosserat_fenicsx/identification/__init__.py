"""Parameter identification of the Ehlers model (thesis chapters 4-6): virtual tests, the
multi-criterion least-squares objective (4.15)-(4.18), (6.3), sensitivities (chapter 5),
SQP via SciPy (section 4.2) and the error analysis of section 4.5.  No dolfinx here."""
