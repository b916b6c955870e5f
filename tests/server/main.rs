//! Integration tests of the knowledge server: the real binary, a real SQLite file in a
//! temporary directory, real HTTP on an ephemeral port.

mod cli;
mod concurrency;
mod faults;
mod flow;
mod hardening;
mod harness;
mod import;
mod jobs;
mod layers;
mod lod;
mod lumigraph;
mod merge;
mod openapi;
mod pages;
mod public;
mod render;
mod security;
mod selection;
mod uploads;
mod viewer;
