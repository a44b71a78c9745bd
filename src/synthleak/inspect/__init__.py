"""Look at the data: contact sheets of rendered sequences and top-down plans of stages (``synthleak show``)."""

from synthleak.inspect.contact_sheet import contact_sheet, id_colour, projected_boxes
from synthleak.inspect.plan_view import plan_view

__all__ = ["contact_sheet", "id_colour", "plan_view", "projected_boxes"]
