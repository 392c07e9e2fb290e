"""Parameter identification: cost, sensitivity to the steps, re-identification from virtual
data, identification of the micropolar parameters from biaxial runs."""
