"""The dashboard's views: each a ``pn.viewable.Viewer`` that renders the :class:`State`."""

from .analysis import AnalysisPanel, InjectPanel
from .criterion import CriterionView, RiskView
from .controls import Controls, FilePanel, SelectionPanel, TaskPanel
from .hypotheses import HypothesisPanel
from .image import ImageResidualView
from .maps import ExternalMap, LayoutMap, MDBMap, RedundancyMap, ResidualMap
from .precision import PrecisionMap
from .summary import SummaryHeader
from .suspects import SuspectsView
from .table import TestsTable
from .teaching import TeachingView

#: The map tabs, in their order.
MAP_VIEWS = (LayoutMap, RedundancyMap, ResidualMap, ExternalMap, MDBMap, PrecisionMap)

__all__ = ["AnalysisPanel", "InjectPanel", "Controls", "FilePanel", "SelectionPanel", "HypothesisPanel", "MAP_VIEWS", "ExternalMap",
           "ImageResidualView", "LayoutMap", "MDBMap", "PrecisionMap", "RedundancyMap", "ResidualMap",
           "SummaryHeader", "SuspectsView", "TaskPanel", "TestsTable", "TeachingView", "CriterionView", "RiskView"]
