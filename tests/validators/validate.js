#!/usr/bin/env node
// Runs the Khronos glTF-Validator (npm package `gltf-validator`) on the files
// given on the command line and prints each report's issue counts and its
// errors and warnings. Exit status: 0 when no file has an error (with
// `--strict`: no error and no warning), 1 otherwise, 2 on bad usage or when a
// file cannot be read or parsed at all.
//
// Usage: node tests/validators/validate.js [--strict] FILE.gltf|FILE.glb ...
'use strict';

const fs = require('fs');
const path = require('path');

let validator;
try {
  validator = require('gltf-validator');
} catch (e) {
  console.error('gltf-validator is not installed: run `npm install` in tests/validators');
  process.exit(2);
}

async function validateFile(file) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const dir = path.dirname(path.resolve(file));
  return validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 0, // unlimited
    writeTimestamp: false,
    // External buffers are loaded relative to the file, like knitvox's DirResources.
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        const p = path.resolve(dir, decodeURIComponent(uri));
        fs.readFile(p, (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
      }),
  });
}

async function main() {
  const args = process.argv.slice(2);
  const strict = args.includes('--strict');
  const files = args.filter((a) => a !== '--strict');
  if (files.length === 0) {
    console.error('usage: validate.js [--strict] FILE...');
    return 2;
  }
  console.log(`gltf-validator ${validator.version()}`);
  let failed = false;
  for (const file of files) {
    let report;
    try {
      report = await validateFile(file);
    } catch (e) {
      console.log(`${file}: cannot validate: ${e}`);
      return 2;
    }
    const i = report.issues;
    console.log(
      `${file}: errors=${i.numErrors} warnings=${i.numWarnings} infos=${i.numInfos} hints=${i.numHints}`
    );
    for (const m of i.messages) {
      // severity: 0 error, 1 warning, 2 info, 3 hint
      if (m.severity <= 1) {
        const kind = m.severity === 0 ? 'ERROR' : 'WARNING';
        console.log(`  ${kind} ${m.code} at ${m.pointer || m.offset || ''}: ${m.message}`);
      }
    }
    if (i.numErrors > 0 || (strict && i.numWarnings > 0)) failed = true;
  }
  return failed ? 1 : 0;
}

main().then(
  (code) => process.exit(code),
  (e) => {
    console.error(e);
    process.exit(2);
  }
);
