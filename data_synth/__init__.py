"""The virtual gonioreflectometer (measurement plans, noise, dataset recipes).

Built by the fitting issue; this package exists now so that the distribution layout is final.
"""
