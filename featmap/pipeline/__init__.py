"""One run of featmap: the loop, the segment cache, the executor, the run folder and the run's config.

- :mod:`run`: :class:`MappingPipeline` (a scan source in, a run folder out);
- :mod:`extract`: every scan through the segment store and an executor;
- :mod:`fuse`: fusion with several methods, timed; the fusion-only job;
- :mod:`segment_store`: the content-keyed per-scan cache;
- :mod:`run_folder`: whole-run atomic writes, the lock, and reading a run back;
- :mod:`executor`: serial or local-process execution;
- :mod:`config`: the composed configuration.
"""

from featmap.pipeline.config import FeatmapConfig, load_config, save_config
from featmap.pipeline.executor import ProcessExecutor, SerialExecutor, local_executor
from featmap.pipeline.run import MappingPipeline, RunResult
from featmap.pipeline.segment_store import SegmentStore

__all__ = ["FeatmapConfig", "MappingPipeline", "ProcessExecutor", "RunResult", "SegmentStore", "SerialExecutor",
           "load_config", "local_executor", "save_config"]
