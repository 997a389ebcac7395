"""The dashboard's views: each a ``pn.viewable.Viewer`` that renders the :class:`State`."""

from .analysis import AnalysisPanel, InjectPanel
from .criterion import CriterionView, RiskView
from .controls import Controls, FilePanel, SelectionPanel, TaskPanel
from .hypotheses import HypothesisPanel
from .maps import (MAP_VIEWS, ExternalMap, ImageResidualView, LayoutMap, MDBMap, PrecisionMap,
                   RedundancyMap, ResidualMap)
from .summary import SummaryHeader
from .suspects import SuspectsView
from .table import TestsTable
from .teaching import TeachingView

__all__ = ["AnalysisPanel", "InjectPanel", "Controls", "FilePanel", "SelectionPanel", "HypothesisPanel", "MAP_VIEWS", "ExternalMap",
           "ImageResidualView", "LayoutMap", "MDBMap", "PrecisionMap", "RedundancyMap", "ResidualMap",
           "SummaryHeader", "SuspectsView", "TaskPanel", "TestsTable", "TeachingView", "CriterionView", "RiskView"]
