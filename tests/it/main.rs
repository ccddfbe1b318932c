//! Server integration tests: the real server on port 0, driven over HTTP.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod admission;
mod api;
mod clouds;
mod common;
mod conformance;
mod dust;
mod faults;
mod hardening;
mod load_balancer;
mod maps;
mod ogc;
mod openapi;
mod overload;
mod restart;
mod scale;
mod security;
mod shared_store;
mod snow_cover;
mod snow_terrain;
mod web;
