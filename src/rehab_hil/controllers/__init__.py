"""Controllers declared like plants: one module per controller, each one ``ControllerSpec`` (its
settings table, what it needs of a plant, and the parts it builds). ``controllers()`` finds them
by scanning this package; ``build_controller`` turns a config into a checked controller that runs
offline with the plant model (``closed_loop``) and on the rig (``loop/controllers.py``)."""

from rehab_hil.controllers.base import (
    DT,
    ControlContext,
    Controller,
    ControllerError,
    ControllerSpec,
    Plan,
    Reference,
    closed_loop,
    controller_names,
    controllers,
    get_controller,
    offline_session,
)
from rehab_hil.controllers.build import build_controller, preflight, settings_for, validate_controllers

__all__ = ["DT", "ControlContext", "Controller", "ControllerError", "ControllerSpec", "Plan", "Reference",
           "build_controller", "closed_loop", "controller_names", "controllers", "get_controller", "offline_session",
           "preflight", "settings_for", "validate_controllers"]
