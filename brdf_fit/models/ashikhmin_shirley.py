"""Placeholder: this catalogue module is being written (issue 6); it registers nothing yet."""


def registry_entries():
    return []
