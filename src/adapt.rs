//! On-demand few-shot adaptation (in progress).
