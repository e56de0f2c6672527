"""Campaigns: many offline closed-loop runs of the product's controllers, on Dask.

One campaign is a matrix of cases (start grade, grade legs, disturbances) ×
strategies × noise seeds (:mod:`~services.campaign.spec`, the JSON shape of
DESIGN.md "Campaigns"). Each run is the closed loop the studies use
(:mod:`~services.campaign.runs`), identified by a hash of what makes it
different (:mod:`~services.campaign.identity`), one Dask task per run
(:mod:`~services.campaign.driver`), scored by :mod:`~services.campaign.metrics`,
kept in a results directory (:mod:`~services.campaign.store`) and summarized by a
report (:mod:`~services.campaign.report`, figures in
:mod:`~services.campaign.figures`). Only the command line imports this package.
"""
